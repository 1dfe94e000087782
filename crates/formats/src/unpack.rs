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
            format!("unpacks to more than {MAX_RATIO} bytes per compressed byte (a corrupt or hostile block)"),
        ));
    }
    Ok(n)
}
