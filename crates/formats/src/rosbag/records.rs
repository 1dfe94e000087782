//! A bag's top-level records: read one by one from the file, chunks handed to `chunk`,
//! connections registered.

use std::io::{self, Read};

use super::{connection, field, BagReader, Connection, EVENT_TYPES, OP_CHUNK, OP_CONNECTION};

/// Appends up to `n` bytes of `src` to `buf` (fewer only at the end of the input). Nothing is
/// reserved from `n`: the buffer grows with the bytes that come, so a corrupt length costs no
/// more memory than the input holds (the buffers keep their capacity from record to record).
pub(super) fn read_up_to<R: Read>(src: &mut R, buf: &mut Vec<u8>, n: u64) -> io::Result<u64> {
    Ok(src.take(n).read_to_end(buf)? as u64)
}

/// How one top-level record read ended.
pub(super) enum Read1 {
    /// A whole record: its header in `header`, its data in `raw` (or skipped).
    Whole,
    /// The input ended before the record did, after this many of its bytes.
    Cut(u64),
    /// The input ended between records.
    End,
}

impl<R: Read> BagReader<R> {
    /// Registers a connection record (None: one that does not parse).
    pub(super) fn register(&mut self, conn: Option<Connection>) {
        match conn {
            Some(c) => {
                self.wanted.remove(&c.id);
                self.connections.insert(c.id, c);
            }
            None => self.stats.unknown_words += 1,
        }
    }

    pub(super) fn is_wanted(&mut self, id: u32) -> bool {
        if let Some(&w) = self.wanted.get(&id) {
            return w;
        }
        let w = !self.skimming
            && self.connections.get(&id).is_some_and(|c| {
                EVENT_TYPES.contains(&c.msgtype.as_str())
                    && self.topic.as_deref().is_none_or(|t| t == c.topic)
            });
        self.wanted.insert(id, w);
        w
    }

    /// Reads the next top-level record: a chunk becomes the current chunk; a connection is
    /// registered; anything else is skipped.
    pub(super) fn next_record(&mut self) -> io::Result<()> {
        self.end_chunk();
        let read = self.read_record()?;
        if let Read1::Cut(n) = read {
            self.stats.truncated_bytes += n;
        }
        if matches!(read, Read1::End) {
            return Ok(());
        }
        let op = field(&self.header, b"op").and_then(|op| op.first().copied());
        let cut = matches!(read, Read1::Cut(_));
        match op {
            Some(OP_CHUNK) => self.unpack_chunk(cut),
            Some(OP_CONNECTION) if !cut => {
                let conn = connection(&self.header, &self.raw);
                self.register(conn);
            }
            _ => {}
        }
        Ok(())
    }

    /// One top-level record: its header into `header`, its data into `raw` for chunks and
    /// connections (skipped otherwise).
    pub(super) fn read_record(&mut self) -> io::Result<Read1> {
        self.header.clear();
        self.raw.clear();
        let mut len = [0u8; 4];
        let got = read_up_to(&mut self.src, &mut self.header, 4)?;
        if got < 4 {
            self.eof = true;
            return Ok(if got == 0 {
                Read1::End
            } else {
                Read1::Cut(got)
            });
        }
        len.copy_from_slice(&self.header[..4]);
        let header_len = u32::from_le_bytes(len) as u64;
        self.header.clear();
        let mut done = 4 + read_up_to(&mut self.src, &mut self.header, header_len)?;
        if done < 4 + header_len {
            self.eof = true;
            return Ok(Read1::Cut(done));
        }
        let got = read_up_to(&mut self.src, &mut self.raw, 4)?;
        done += got;
        if got < 4 {
            self.eof = true;
            return Ok(Read1::Cut(done));
        }
        len.copy_from_slice(&self.raw[..4]);
        let data_len = u32::from_le_bytes(len) as u64;
        self.raw.clear();
        let op = field(&self.header, b"op").and_then(|op| op.first().copied());
        let got = if matches!(op, Some(OP_CHUNK | OP_CONNECTION)) {
            read_up_to(&mut self.src, &mut self.raw, data_len)?
        } else {
            io::copy(&mut (&mut self.src).take(data_len), &mut io::sink())?
        };
        done += got;
        if got < data_len {
            self.eof = true;
            return Ok(Read1::Cut(done));
        }
        Ok(Read1::Whole)
    }
}
