//! The records inside a bag's chunk: an uncompressed or small chunk in memory, a large
//! compressed one streamed through the window (see the module's notes in `rosbag`).

use std::io::{self, Read};

use super::{
    connection, field, field_u32, BagReader, EVENT, IN_MEMORY, OP_CONNECTION, OP_MESSAGE, WINDOW,
};
use crate::bytes::u32_at;
use crate::unpack;

/// A compressed chunk's decoder, owning its compressed bytes, reading at most its declared size.
pub(super) enum Unpack {
    Lz4(io::Take<lz4_flex::frame::FrameDecoder<io::Cursor<Vec<u8>>>>),
    Bz2(io::Take<bzip2::read::BzDecoder<io::Cursor<Vec<u8>>>>),
}

impl Unpack {
    fn new(lz4: bool, packed: Vec<u8>, size: u64) -> Self {
        let packed = io::Cursor::new(packed);
        if lz4 {
            Self::Lz4(lz4_flex::frame::FrameDecoder::new(packed).take(size))
        } else {
            Self::Bz2(bzip2::read::BzDecoder::new(packed).take(size))
        }
    }

    fn into_packed(self) -> Vec<u8> {
        match self {
            Self::Lz4(d) => d.into_inner().into_inner().into_inner(),
            Self::Bz2(d) => d.into_inner().into_inner().into_inner(),
        }
    }

    pub(super) fn packed_capacity(&self) -> usize {
        match self {
            Self::Lz4(d) => d.get_ref().get_ref().get_ref().capacity(),
            Self::Bz2(d) => d.get_ref().get_ref().get_ref().capacity(),
        }
    }
}

impl Read for Unpack {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Self::Lz4(d) => d.read(buf),
            Self::Bz2(d) => d.read(buf),
        }
    }
}

/// Appends bytes of `src` to `buf` until it holds `len` bytes (fewer only at the end of the
/// input). Unlike `read_up_to`, the buffer's capacity grows (by doubling, from what the bytes
/// need) to at most `len`, never past it: the window of a streamed chunk stays its size.
fn read_into<R: Read>(src: &mut R, buf: &mut Vec<u8>, len: usize) -> io::Result<u64> {
    let start = buf.len();
    let mut filled = start;
    while filled < len {
        if filled == buf.len() {
            if buf.len() == buf.capacity() {
                let grow = buf.capacity().max(32).min(len - buf.len());
                buf.reserve_exact(grow);
            }
            // Zeroed a step at a time and once: a decoder's small reads fill what is zeroed.
            let zeroed = buf.capacity().min(len).min(filled + (1 << 18));
            buf.resize(zeroed, 0);
        }
        let got = match src.read(&mut buf[filled..]) {
            Ok(got) => got,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => {
                buf.truncate(filled);
                return Err(e);
            }
        };
        filled += got;
        if got == 0 {
            break;
        }
    }
    buf.truncate(filled);
    Ok((filled - start) as u64)
}

impl<R: Read> BagReader<R> {
    /// Bytes of the current chunk from `pos` on (in the window or still in the decoder).
    pub(super) fn remaining(&self) -> u64 {
        (self.chunk.len() - self.pos) as u64 + self.chunk_left
    }

    /// Makes the window hold `n` bytes from `pos` (n at most `IN_MEMORY`), unpacking more of a
    /// streamed chunk; false when the chunk ends first.
    pub(super) fn fill(&mut self, n: usize) -> bool {
        let have = self.chunk.len() - self.pos;
        if have >= n {
            return true;
        }
        let need = (n - have) as u64;
        let Some(stream) = self.stream.as_mut().filter(|_| need <= self.chunk_left) else {
            return false;
        };
        self.chunk.drain(..self.pos);
        self.pos = 0;
        let want = need.max(WINDOW as u64).min(self.chunk_left);
        let len = self.chunk.len() + want as usize;
        match read_into(stream, &mut self.chunk, len) {
            Ok(got) if got == want => {
                self.chunk_left -= got;
                true
            }
            // The first pass decoded these bytes; a decoder that fails now ends the chunk.
            _ => {
                self.end_chunk();
                false
            }
        }
    }

    /// Moves `pos` on by `n` bytes, unpacking (and dropping) a streamed chunk's bytes past the
    /// window; false when the chunk ends first.
    pub(super) fn skip(&mut self, n: u64) -> bool {
        let have = (self.chunk.len() - self.pos) as u64;
        if n <= have {
            self.pos += n as usize;
            return true;
        }
        let rest = n - have;
        let Some(stream) = self.stream.as_mut().filter(|_| rest <= self.chunk_left) else {
            return false;
        };
        self.chunk.clear();
        self.pos = 0;
        match io::copy(&mut stream.by_ref().take(rest), &mut io::sink()) {
            Ok(got) if got == rest => {
                self.chunk_left -= rest;
                true
            }
            _ => {
                self.end_chunk();
                false
            }
        }
    }

    /// The u32 at `at` bytes from `pos`, unpacking up to it.
    pub(super) fn peek_u32(&mut self, at: usize) -> Option<u32> {
        self.fill(at + 4)
            .then(|| u32_at(&self.chunk, self.pos + at))?
    }

    /// Drops the rest of the current chunk (its decoder's bytes go back to `raw`).
    pub(super) fn end_chunk(&mut self) {
        self.chunk.clear();
        self.pos = 0;
        self.chunk_left = 0;
        self.pending = 0;
        if let Some(stream) = self.stream.take() {
            self.raw = stream.into_packed();
            self.raw.clear();
        }
    }

    /// The record at `pos` in the current chunk.
    pub(super) fn next_in_chunk(&mut self) {
        let streamed = self.stream.is_some();
        let Some(header_len) = self.peek_u32(0).map(|n| n as usize) else {
            return self.corrupt_chunk();
        };
        // Only a streamed chunk limits a header: an unpacked-whole one is already in memory.
        let head = 8 + header_len;
        if streamed && head > IN_MEMORY {
            return self.corrupt_chunk();
        }
        let Some(data_len) = self.peek_u32(4 + header_len).map(u64::from) else {
            return self.corrupt_chunk();
        };
        if head as u64 + data_len > self.remaining() {
            return self.corrupt_chunk();
        }
        let header = &self.chunk[self.pos + 4..self.pos + 4 + header_len];
        match field(header, b"op").and_then(|op| op.first().copied()) {
            Some(OP_CONNECTION) => {
                let whole = head as u64 + data_len;
                if whole > IN_MEMORY as u64 && streamed {
                    self.register(None);
                    self.skip(whole);
                    return;
                }
                if !self.fill(whole as usize) {
                    return;
                }
                let at = self.pos;
                let conn = connection(
                    &self.chunk[at + 4..at + 4 + header_len],
                    &self.chunk[at + head..at + whole as usize],
                );
                self.pos += whole as usize;
                self.register(conn);
            }
            Some(OP_MESSAGE) => {
                let id = field_u32(header, b"conn");
                self.skip(head as u64);
                if !id.is_some_and(|id| self.is_wanted(id)) {
                    self.skip(data_len);
                    return;
                }
                match self.event_array_prefix(data_len) {
                    Ok((width, height, n)) => {
                        self.size.get_or_insert((width, height));
                        self.pending = n;
                    }
                    Err(read) => {
                        self.stats.unknown_words += 1;
                        self.skip(data_len - read);
                    }
                }
            }
            _ => {
                self.skip(head as u64 + data_len);
            }
        }
    }

    /// A record cut by its chunk's end: a corrupt chunk, or one the file ends in (whose bytes
    /// `truncated_bytes` already counts); the rest of the chunk is dropped.
    pub(super) fn corrupt_chunk(&mut self) {
        if !self.eof {
            self.stats.unknown_words += 1;
        }
        self.end_chunk();
    }

    /// With `pos` at a message's `data_len` bytes of data, all in the chunk: the EventArray's
    /// (width, height, event count) with `pos` moved to its first event, or, when the bytes
    /// are not exactly that layout (see `event_array`), how many of them were passed.
    pub(super) fn event_array_prefix(&mut self, data_len: u64) -> Result<(u32, u32, usize), u64> {
        if data_len < 16 {
            return Err(0);
        }
        let id_len = u64::from(self.peek_u32(12).ok_or(0u64)?);
        let start = 28 + id_len;
        if start > data_len {
            return Err(0);
        }
        // The frame id is skipped, not held: it may be longer than the window.
        let passed = start - 12;
        if !self.skip(passed) {
            return Err(data_len);
        }
        let height = self.peek_u32(0).ok_or(passed)?;
        let width = self.peek_u32(4).ok_or(passed)?;
        let n = self.peek_u32(8).ok_or(passed)?;
        if u64::from(n) * EVENT as u64 + start != data_len {
            return Err(passed);
        }
        self.pos += 12;
        Ok((width, height, n as usize))
    }

    /// The chunk in `raw` (header in `header`) made the current chunk: an uncompressed chunk
    /// the file ends in keeps its complete records; a cut or corrupt compressed one, none.
    /// A compressed chunk is unpacked whole when it fits `IN_MEMORY`, else streamed (see the
    /// module's notes).
    pub(super) fn unpack_chunk(&mut self, cut: bool) {
        let size = u64::from(field_u32(&self.header, b"size").unwrap_or(0));
        let lz4 = match field(&self.header, b"compression") {
            Some(b"none") => {
                std::mem::swap(&mut self.chunk, &mut self.raw);
                self.largest_chunk = self.largest_chunk.max(self.chunk.len());
                self.unpacked += self.chunk.len() as u64;
                return;
            }
            Some(b"lz4") => true,
            Some(b"bz2") => false,
            _ => {
                if !cut {
                    self.stats.unknown_words += 1;
                }
                return;
            }
        };
        // A compressed chunk is all or nothing: a decoder's output from damaged input
        // depends on where its reads stop, so none of a cut one is kept.
        if cut {
            return;
        }
        // A chunk declared to unpack to more than `unpack::MAX_RATIO` bytes per compressed
        // byte is a decompression bomb: refused whole, before any decoding, so that the time
        // a chunk takes is bounded by its compressed bytes (tests/bag_bomb.rs: bzip2 packs a
        // chunk of zero events ~370,000 times, a sensor's events 13 times).
        if size > unpack::cap(self.raw.len() as u64) {
            self.stats.unknown_words += 1;
            return;
        }
        let mut stream = Unpack::new(lz4, std::mem::take(&mut self.raw), size);
        let total = match read_into(&mut stream, &mut self.chunk, IN_MEMORY) {
            Ok(got) if got < IN_MEMORY as u64 => Ok(got),
            // More than fits: decode the rest to a sink, only to know it decodes.
            Ok(got) => io::copy(&mut stream, &mut io::sink()).map(|rest| got + rest),
            Err(e) => Err(e),
        };
        match total {
            Ok(total) if total > self.chunk.len() as u64 => {
                self.chunk.clear();
                self.stream = Some(Unpack::new(lz4, stream.into_packed(), size));
                self.chunk_left = total;
                self.largest_chunk = self.largest_chunk.max(total as usize);
                self.unpacked += total;
            }
            Ok(total) => {
                self.raw = stream.into_packed();
                self.largest_chunk = self.largest_chunk.max(total as usize);
                self.unpacked += total;
            }
            Err(_) => {
                self.raw = stream.into_packed();
                // What it unpacked before failing still sized the window.
                self.largest_chunk = self.largest_chunk.max(self.chunk.len());
                self.chunk.clear();
                self.stats.unknown_words += 1;
            }
        }
    }
}
