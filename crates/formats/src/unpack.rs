//! Decompression with a bound: a container's compressed block (an AEDAT 4 packet, an MCAP
//! chunk, a .db3 message or file) may unpack to at most `MAX_RATIO` bytes per compressed
//! byte, so that a corrupt or hostile block cannot fill the memory or the disk.

use std::io::{self, Read};

/// Most bytes a block may unpack to per compressed byte (LZ4's own limit, 255, plus a margin;
/// event data compresses a few times at most): a larger output is a decompression bomb.
pub(crate) const MAX_RATIO: u64 = 256;

/// The most bytes `input` compressed bytes may unpack to: `MAX_RATIO` per byte, plus 64 KiB
/// for a small block's fixed overhead.
pub(crate) fn cap(input: u64) -> u64 {
    input.saturating_mul(MAX_RATIO) + (1 << 16)
}

/// Runs `unpack` (reading `dec` to its end into a buffer or a file; returns the bytes it took)
/// on `dec`, the decompressor of `input` bytes, cut at `cap(input)` + 1 bytes: more is an
/// error, refused before the output goes past the cap.
pub(crate) fn bounded<D: Read>(
    dec: D,
    input: u64,
    unpack: impl FnOnce(&mut io::Take<D>) -> io::Result<u64>,
) -> io::Result<u64> {
    let cap = cap(input);
    let n = unpack(&mut dec.take(cap + 1))?;
    if n > cap {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "unpacks to more than {MAX_RATIO} bytes per compressed byte (corrupt or hostile)"
            ),
        ));
    }
    Ok(n)
}

/// A zstd stream read up to where its file was cut: zstd's "incomplete frame" at the end of
/// the input ends the stream there instead of failing, so the container's reader keeps the
/// records unpacked before the cut and counts the one it ends in (`Stats::truncated_bytes`),
/// as it does for a cut uncompressed file. A damaged frame is still an error.
pub(crate) struct EndsWhereCut<R>(pub(crate) R);

impl<R: Read> Read for EndsWhereCut<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.0.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => Ok(0),
            other => other,
        }
    }
}

/// Unpacks the zstd frames of a message-compressed ROS 2 bag (rosbag2's `compression_mode`
/// "message", .db3 or MCAP): one decompression context for all
/// (a fresh one per message cost as much as unpacking a small message) and one buffer.
pub(crate) struct Frames {
    context: zstd::bulk::Decompressor<'static>,
    out: Vec<u8>,
}

impl std::fmt::Debug for Frames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Frames")
            .field("out", &self.out.len())
            .finish_non_exhaustive()
    }
}

impl Frames {
    pub(crate) fn new() -> io::Result<Self> {
        let context = zstd::bulk::Decompressor::new()?;
        Ok(Self {
            context,
            out: Vec::new(),
        })
    }

    /// The last frame unpacked.
    pub(crate) fn out(&self) -> &[u8] {
        &self.out
    }

    /// The bytes its buffer holds room for (the fuzzers' bound).
    #[cfg(any(test, feature = "check"))]
    pub(crate) fn capacity(&self) -> usize {
        self.out.capacity()
    }

    /// `blob` unpacked, within `unpack::cap`: in one call when its frame declares a size under
    /// the cap (rosbag2's do), else (no size, several frames, a bomb) streaming, cut at it.
    pub(crate) fn unpack(&mut self, blob: &[u8]) -> io::Result<&[u8]> {
        self.out.clear();
        let cap = cap(blob.len() as u64);
        if let Ok(Some(size)) = zstd::zstd_safe::get_frame_content_size(blob) {
            if size <= cap {
                self.out.reserve_exact(size as usize);
                let done = self.context.decompress_to_buffer(blob, &mut self.out);
                if done.is_ok_and(|n| n as u64 == size) {
                    return Ok(&self.out);
                }
                self.out.clear();
            }
        }
        let dec = zstd::stream::read::Decoder::with_buffer(blob)?;
        let out = &mut self.out;
        bounded(dec, blob.len() as u64, |d| {
            d.read_to_end(out).map(|n| n as u64)
        })?;
        Ok(&self.out)
    }
}
