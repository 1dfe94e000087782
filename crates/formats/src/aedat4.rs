//! iniVation AEDAT 4 (DV software): the events of one stream, packet by packet.
//!
//! A file is the line `#!AER-DAT4.0\r\n`, a u32 length and the IOHeader flatbuffer
//! (`compression`: 0 none, 1/2 LZ4, 3/4 Zstd; `file_data_position`: where the data table
//! starts, -1 without one; `description`: the streams as DV's XML), then packets: an i32 stream
//! id, a u32 size and the packet, compressed as a whole (an LZ4 or a Zstd frame). A packet is a
//! size-prefixed flatbuffer with a file identifier; an event packet's ("EVTS") table holds
//! `elements: [Event]`, each a 16-byte struct: t i64 (µs), x i16, y i16, on bool, 3 bytes of
//! padding. The data table, when there is one, ends the packets. Memory is the read buffer plus
//! one packet (compressed and uncompressed), whatever the file's length.

use std::io::{self, BufReader, Read};

use crate::bytes::{i64_at, u16_at, u32_at};
use crate::{growing_chunk, unpack, EventSource, Events, Stats};

/// The first line of every AEDAT 4 file.
pub const MAGIC: &[u8] = b"#!AER-DAT4.0\r\n";
/// Bytes per event struct in an event packet.
pub const EVENT: usize = 16;
const EVENTS_ID: &[u8] = b"EVTS";

/// How a file's packets are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    None,
    Lz4,
    Zstd,
}

impl Compression {
    /// The IOHeader's enum (LZ4_HIGH and ZSTD_HIGH decode as LZ4 and Zstd), or None.
    pub fn from_header(value: i32) -> Option<Self> {
        match value {
            0 => Some(Self::None),
            1 | 2 => Some(Self::Lz4),
            3 | 4 => Some(Self::Zstd),
            _ => None,
        }
    }
}

/// What the IOHeader says, and where the packets start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// The IOHeader's compression value (see `Compression::from_header`).
    pub compression: i32,
    /// Where the data table starts (the end of the packets), -1 without one.
    pub data_table: i64,
    /// The streams, as DV's XML.
    pub description: String,
    /// The byte offset of the first packet.
    pub data_start: u64,
}

/// Where field `index` of the flatbuffer table at `table` keeps its value, or None (absent,
/// or the table is malformed).
fn table_field(b: &[u8], table: usize, index: usize) -> Option<usize> {
    let soffset = u32_at(b, table)? as i32 as i64;
    let vtable = usize::try_from(table as i64 - soffset).ok()?;
    let vtable_len = u16_at(b, vtable)? as usize;
    let slot = 4 + 2 * index;
    if slot + 2 > vtable_len {
        return None;
    }
    match u16_at(b, vtable + slot)? as usize {
        0 => None,
        off => table.checked_add(off),
    }
}

/// The target of the uoffset at `at`.
fn follow(b: &[u8], at: usize) -> Option<usize> {
    at.checked_add(u32_at(b, at)? as usize)
}

/// The IOHeader flatbuffer's fields, or None when it is malformed.
fn io_header(b: &[u8]) -> Option<(i32, i64, String)> {
    let table = follow(b, 0)?;
    let compression = match table_field(b, table, 0) {
        Some(at) => u32_at(b, at)? as i32,
        None => 0,
    };
    let data_table = match table_field(b, table, 1) {
        Some(at) => i64_at(b, at)?,
        None => -1,
    };
    let text = follow(b, table_field(b, table, 2)?)?;
    let len = u32_at(b, text)? as usize;
    let bytes = b.get(text + 4..(text + 4).checked_add(len)?)?;
    Some((
        compression,
        data_table,
        String::from_utf8_lossy(bytes).into_owned(),
    ))
}

fn invalid(what: &str) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, what.to_string())
}

/// Reads the line and the IOHeader from the start of `src`.
pub fn read_header<R: Read>(src: &mut R) -> io::Result<Header> {
    let mut magic = Vec::new();
    src.take(MAGIC.len() as u64).read_to_end(&mut magic)?;
    if magic != MAGIC {
        return Err(invalid(
            "not AEDAT 4: it does not start with '#!AER-DAT4.0' (AEDAT 2/3 files: convert them \
             with DV)",
        ));
    }
    let mut len = [0u8; 4];
    src.read_exact(&mut len)
        .map_err(|_| invalid("the file ends inside its header"))?;
    let len = u32::from_le_bytes(len) as u64;
    let mut buf = Vec::new();
    if src.take(len).read_to_end(&mut buf)? as u64 != len {
        return Err(invalid("the file ends inside its header"));
    }
    let (compression, data_table, description) =
        io_header(&buf).ok_or_else(|| invalid("its IOHeader is corrupt"))?;
    Ok(Header {
        compression,
        data_table,
        description,
        data_start: MAGIC.len() as u64 + 4 + len,
    })
}

/// The events of the event packet in `b` as (offset of the first, count), or None when it is
/// not a whole event packet.
fn event_packet(b: &[u8]) -> Option<(usize, usize)> {
    if b.get(8..12)? != EVENTS_ID {
        return None;
    }
    let table = follow(b, 4)?;
    let vector = follow(b, table_field(b, table, 0)?)?;
    let n = u32_at(b, vector)? as usize;
    let start = vector + 4;
    (start.checked_add(n.checked_mul(EVENT)?)? <= b.len()).then_some((start, n))
}

/// The events of stream `stream` in chunks of at most `max_events`, from `src` placed at the
/// first packet (byte `data_start`) to the data table (`data_table`, or the end without one).
/// `stats()`: `unknown_words` counts packets of the stream that are not whole event packets
/// (corrupt, or not decompressible), `truncated_bytes` the bytes of a packet the file ends in.
#[derive(Debug)]
pub struct AedatReader<R> {
    src: BufReader<R>,
    compression: Compression,
    stream: i32,
    /// Bytes to the data table (None: to the end).
    left: Option<u64>,
    raw: Vec<u8>,
    packet: Vec<u8>,
    /// The packet being emitted: (offset of its next event in `packet`, events left).
    pending: Option<(usize, usize)>,
    eof: bool,
    largest: usize,
    unpacked: u64,
    stats: Stats,
}

impl<R: Read> AedatReader<R> {
    /// A reader through a read buffer of `block` bytes.
    pub fn new(
        src: R,
        compression: Compression,
        stream: i32,
        data_start: u64,
        data_table: i64,
        block: usize,
    ) -> Self {
        let left = u64::try_from(data_table)
            .ok()
            .map(|end| end.saturating_sub(data_start));
        Self {
            src: BufReader::with_capacity(block.max(1), src),
            compression,
            stream,
            left,
            raw: Vec::new(),
            packet: Vec::new(),
            pending: None,
            eof: false,
            largest: 0,
            unpacked: 0,
            stats: Stats::default(),
        }
    }

    /// The capacities of the packet buffers (compressed, uncompressed), the most bytes one
    /// packet unpacked to and the bytes all unpacked to so far (the fuzzers' bounds).
    pub fn buffers(&self) -> ([usize; 2], usize, u64) {
        let caps = [self.raw.capacity(), self.packet.capacity()];
        (caps, self.largest, self.unpacked)
    }

    /// Up to `n` bytes of the source into `buf` (replaced), counted against the data table.
    fn read(&mut self, n: u64, keep: bool) -> io::Result<u64> {
        let n = self.left.map_or(n, |left| n.min(left));
        let got = if keep {
            self.raw.clear();
            (&mut self.src).take(n).read_to_end(&mut self.raw)? as u64
        } else {
            io::copy(&mut (&mut self.src).take(n), &mut io::sink())?
        };
        if let Some(left) = self.left.as_mut() {
            *left -= got;
        }
        Ok(got)
    }

    /// Reads the next packet; one of the stream becomes the pending events.
    fn next_packet(&mut self) -> io::Result<()> {
        self.pending = None;
        let got = self.read(8, true)?;
        if got < 8 {
            self.eof = true;
            self.stats.truncated_bytes += got;
            return Ok(());
        }
        let id = i32::from_le_bytes([self.raw[0], self.raw[1], self.raw[2], self.raw[3]]);
        let size = u32::from_le_bytes([self.raw[4], self.raw[5], self.raw[6], self.raw[7]]) as u64;
        let ours = id == self.stream;
        let got = self.read(size, ours)?;
        if got < size {
            // A packet the file (or the space before the data table) ends in: dropped whole.
            self.eof = true;
            self.stats.truncated_bytes += 8 + got;
            return Ok(());
        }
        if !ours {
            return Ok(());
        }
        self.packet.clear();
        let unpacked = match self.compression {
            Compression::None => {
                std::mem::swap(&mut self.packet, &mut self.raw);
                Ok(())
            }
            Compression::Lz4 => {
                let dec = lz4_flex::frame::FrameDecoder::new(&self.raw[..]);
                bounded(dec, self.raw.len(), &mut self.packet)
            }
            Compression::Zstd => zstd::stream::read::Decoder::with_buffer(&self.raw[..])
                .and_then(|dec| bounded(dec, self.raw.len(), &mut self.packet)),
        };
        self.largest = self.largest.max(self.packet.len());
        match unpacked.ok().and_then(|_| event_packet(&self.packet)) {
            Some(events) => {
                self.unpacked += self.packet.len() as u64;
                self.pending = Some(events);
            }
            None => {
                self.packet.clear();
                self.stats.unknown_words += 1;
            }
        }
        Ok(())
    }
}

impl<R: Read> EventSource for AedatReader<R> {
    fn stats(&self) -> Stats {
        self.stats
    }

    fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        let mut out = growing_chunk(max_events);
        while out.len() < max_events {
            let Some((at, left)) = self.pending.filter(|&(_, left)| left > 0) else {
                if self.eof {
                    break;
                }
                self.next_packet()?;
                continue;
            };
            let take = left.min(max_events - out.len());
            let records = self.packet[at..at + take * EVENT].chunks_exact(EVENT);
            let i16_at = |r: &[u8], i: usize| i16::from_le_bytes([r[i], r[i + 1]]) as u16;
            out.t.extend(
                records
                    .clone()
                    .map(|r| i64::from_le_bytes([r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7]])),
            );
            out.x.extend(records.clone().map(|r| i16_at(r, 8)));
            out.y.extend(records.clone().map(|r| i16_at(r, 10)));
            out.p.extend(records.map(|r| (r[12] != 0) as i8));
            self.pending = Some((at + take * EVENT, left - take));
        }
        Ok(out)
    }
}

/// Decompresses a packet of `input` bytes into `out`, within `unpack::cap(input)`.
fn bounded<D: Read>(dec: D, input: usize, out: &mut Vec<u8>) -> io::Result<()> {
    unpack::bounded(dec, input as u64, |d| d.read_to_end(out).map(|n| n as u64)).map(drop)
}
