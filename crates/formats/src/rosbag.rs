//! ROS 1 bags (format 2.0): the event arrays of one topic (`dvs_msgs/EventArray` from
//! rpg_dvs_ros, `prophesee_event_msgs/EventArray` from prophesee_ros_driver), read record by
//! record and returned in chunks of events.
//!
//! A bag is the line `#ROSBAG V2.0` and then records: a u32 header length, the header's fields
//! (each a u32 length and `name=value`), a u32 data length and the data. Op 0x03 is the bag
//! header (with `index_pos`), 0x05 a chunk (`compression` none, lz4 or bz2, `size` uncompressed
//! bytes) whose data holds connection (0x07: `conn`, `topic`; data: `type`, `md5sum`, ...) and
//! message records (0x02: `conn`, `time`); 0x04 and 0x06 index the chunks, and the connection
//! records come again after the chunks, at `index_pos`. The reader goes through the records in
//! file order and needs no index, so a bag whose recording was cut off (unindexed, its last
//! chunk incomplete) reads up to its last complete message.
//!
//! An EventArray in ROS 1 serialisation is packed little-endian: Header (seq, stamp sec, nsec,
//! frame_id as u32 length + bytes), height, width, u32 event count, then 13 bytes per event:
//! x u16, y u16, ts sec u32, ts nsec u32, polarity u8.
//!
//! Memory is the read buffer, one chunk's compressed bytes and a window of its unpacked records
//! of at most `MAX_WINDOW` bytes, whatever the bag's length or a chunk's declared `size`; time
//! is bounded by the compressed bytes, as a chunk declared to unpack to more than
//! `unpack::MAX_RATIO` bytes per compressed byte (a decompression bomb) is refused undecoded. A
//! compressed chunk that unpacks to at most `IN_MEMORY` bytes is unpacked whole; a larger one
//! (a bag written with very large chunks) is unpacked twice: once to a sink, to know
//! that it decodes (a compressed chunk is all or nothing), then through the window, its records
//! parsed as they come out. The decompressors' own block buffers are sized by their stream
//! headers: at most 12.1 MiB for LZ4 (4 MiB blocks, linked) and 3.6 MB for bzip2 (level 9).

use std::collections::HashMap;
use std::io::{self, BufReader, Read, Seek, SeekFrom};

use crate::bytes::u32_at;
use crate::{growing_chunk, unpack, EventSource, Events, Stats};

/// The first line of every ROS 1 bag this reader reads.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
/// The event-array message types (ROS 1 names), with the layout above.
pub const EVENT_TYPES: [&str; 2] = ["dvs_msgs/EventArray", "prophesee_event_msgs/EventArray"];
/// Bytes per serialised event.
pub const EVENT: usize = 13;

const OP_MESSAGE: u8 = 0x02;
const OP_CHUNK: u8 = 0x05;
const OP_CONNECTION: u8 = 0x07;
const OP_BAG_HEADER: u8 = 0x03;

/// A compressed chunk unpacking to at most this many bytes is unpacked whole (one decode);
/// writers' chunks are 768 KiB (rosbag) to 1 MiB (rosbags).
#[cfg(not(any(test, fuzzing)))]
pub const IN_MEMORY: usize = 8 << 20;
/// Bytes read into the window of a streamed chunk at a time.
#[cfg(not(any(test, fuzzing)))]
const WINDOW: usize = 1 << 20;
/// The same, small in the unit tests and the fuzz targets: their inputs of a few KB then go
/// through both paths (the seeds' chunks are streamed, the hand-made ones mostly not).
#[cfg(any(test, fuzzing))]
pub const IN_MEMORY: usize = 1 << 10;
#[cfg(any(test, fuzzing))]
const WINDOW: usize = 1 << 8;
/// The most bytes the window of a chunk holds: a record header, or a whole connection record,
/// of a streamed chunk may be at most `IN_MEMORY` bytes (longer ones could not be part of an
/// unpacked-whole chunk either; they make the chunk corrupt), plus one read.
pub const MAX_WINDOW: usize = IN_MEMORY + WINDOW;

/// A topic's connection: its id in the bag, topic and message type (ROS 1 name).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Connection {
    pub id: u32,
    pub topic: String,
    pub msgtype: String,
}

/// The value of field `name` in a record header, or None (absent or a malformed header).
fn field<'a>(header: &'a [u8], name: &[u8]) -> Option<&'a [u8]> {
    let mut rest = header;
    while rest.len() >= 4 {
        let len = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]) as usize;
        let body = rest.get(4..4usize.checked_add(len)?)?;
        if let Some(eq) = body.iter().position(|&b| b == b'=') {
            if &body[..eq] == name {
                return Some(&body[eq + 1..]);
            }
        }
        rest = &rest[4 + len..];
    }
    None
}

fn field_u32(header: &[u8], name: &[u8]) -> Option<u32> {
    let v = field(header, name)?;
    Some(u32::from_le_bytes(v.try_into().ok()?))
}

fn field_u64(header: &[u8], name: &[u8]) -> Option<u64> {
    let v = field(header, name)?;
    Some(u64::from_le_bytes(v.try_into().ok()?))
}

fn field_str(header: &[u8], name: &[u8]) -> Option<String> {
    field(header, name).map(|v| String::from_utf8_lossy(v).into_owned())
}

/// An EventArray's (width, height, offset of its first event, event count), or None when the
/// bytes are not exactly that layout (the length check guards against any other message).
pub fn event_array(data: &[u8]) -> Option<(u32, u32, usize, usize)> {
    let id_len = u32_at(data, 12)? as usize;
    let start = 16usize.checked_add(id_len)?.checked_add(12)?;
    let height = u32_at(data, start - 12)?;
    let width = u32_at(data, start - 8)?;
    let n = u32_at(data, start - 4)? as usize;
    (n.checked_mul(EVENT)?.checked_add(start)? == data.len()).then_some((width, height, start, n))
}

/// Appends up to `n` bytes of `src` to `buf` (fewer only at the end of the input). Nothing is
/// reserved from `n`: the buffer grows with the bytes that come, so a corrupt length costs no
/// more memory than the input holds (the buffers keep their capacity from record to record).
fn read_up_to<R: Read>(src: &mut R, buf: &mut Vec<u8>, n: u64) -> io::Result<u64> {
    Ok(src.take(n).read_to_end(buf)? as u64)
}

/// A compressed chunk's decoder, owning its compressed bytes, reading at most its declared size.
enum Unpack {
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

    fn packed_capacity(&self) -> usize {
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

/// How one top-level record read ended.
enum Read1 {
    /// A whole record: its header in `header`, its data in `raw` (or skipped).
    Whole,
    /// The input ended before the record did, after this many of its bytes.
    Cut(u64),
    /// The input ended between records.
    End,
}

/// The events of the chosen topic's EventArray messages, in file order, in chunks of at most
/// `max_events`; what it could not read is counted in `stats()`: `unknown_words` are records
/// that are not what their header says (event messages of another layout, corrupt or
/// unknown-compression chunks), `truncated_bytes` the bytes of a last record the file ends in.
pub struct BagReader<R> {
    src: BufReader<R>,
    /// The topic to read; None: every connection of an event-array type.
    topic: Option<String>,
    /// Connections only, no events (`skim`).
    skimming: bool,
    header: Vec<u8>,
    raw: Vec<u8>,
    /// The window of the current chunk's unpacked records and the position in it; the
    /// whole chunk unless `stream` holds the rest.
    chunk: Vec<u8>,
    pos: usize,
    /// A streamed chunk's decoder and the bytes of the chunk it has yet to give.
    stream: Option<Unpack>,
    chunk_left: u64,
    /// Events left in the message being emitted (the next one at `pos`).
    pending: usize,
    connections: HashMap<u32, Connection>,
    wanted: HashMap<u32, bool>,
    size: Option<(u32, u32)>,
    largest_chunk: usize,
    unpacked: u64,
    eof: bool,
    stats: Stats,
}

impl<R> std::fmt::Debug for BagReader<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagReader")
            .field("topic", &self.topic)
            .field("pos", &self.pos)
            .field("chunk_left", &self.chunk_left)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl<R: Read> BagReader<R> {
    /// A reader of `src` (at the start of the bag) for `topic` (None: every event-array
    /// connection), through a read buffer of `block` bytes (a chunk's data larger than that is
    /// read past it). Fails when the input does not start with the bag line.
    pub fn new(src: R, topic: Option<&str>, block: usize) -> io::Result<Self> {
        let mut reader = Self::at(src, topic, block);
        let mut magic = Vec::with_capacity(MAGIC.len());
        read_up_to(&mut reader.src, &mut magic, MAGIC.len() as u64)?;
        if magic != MAGIC {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "not a ROS 1 bag: it does not start with '#ROSBAG V2.0' (ROS 2 bags are \
                 .db3/.mcap; re-record or convert with rosbag)",
            ));
        }
        Ok(reader)
    }

    /// A reader of `src` placed at a record by the caller.
    fn at(src: R, topic: Option<&str>, block: usize) -> Self {
        Self {
            src: BufReader::with_capacity(block.max(1), src),
            topic: topic.map(str::to_string),
            skimming: false,
            header: Vec::new(),
            raw: Vec::new(),
            chunk: Vec::new(),
            pos: 0,
            stream: None,
            chunk_left: 0,
            pending: 0,
            connections: HashMap::new(),
            wanted: HashMap::new(),
            size: None,
            largest_chunk: 0,
            unpacked: 0,
            eof: false,
            stats: Stats::default(),
        }
    }

    /// The connections seen so far, by id.
    pub fn connections(&self) -> Vec<Connection> {
        let mut all: Vec<_> = self.connections.values().cloned().collect();
        all.sort_by_key(|c| c.id);
        all
    }

    /// The capacities of the reader's buffers (record header, compressed data, chunk window),
    /// the most bytes one chunk unpacked to and the bytes all chunks unpacked to so far: the
    /// fuzzers bound the buffers by the input and the window, the events by the total.
    pub fn buffers(&self) -> ([usize; 3], usize, u64) {
        let packed = self.stream.as_ref().map_or(0, Unpack::packed_capacity);
        let caps = [
            self.header.capacity(),
            self.raw.capacity() + packed,
            self.chunk.capacity(),
        ];
        (caps, self.largest_chunk, self.unpacked)
    }

    /// The (width, height) of the first event message, reading up to it (its events are still
    /// returned by `next_chunk`); None when the topic has no readable event message.
    pub fn sensor_size(&mut self) -> io::Result<Option<(u32, u32)>> {
        while self.size.is_none() && self.advance()? {}
        Ok(self.size)
    }

    /// Reads through the bag to its end, registering its connections; no events.
    pub fn skim(&mut self) -> io::Result<()> {
        self.skimming = true;
        self.wanted.clear();
        while self.advance()? {}
        Ok(())
    }

    /// Steps until a message with events left is pending (true) or the input ends (false).
    fn advance(&mut self) -> io::Result<bool> {
        loop {
            if self.pending > 0 {
                return Ok(true);
            }
            if self.remaining() > 0 {
                self.next_in_chunk();
                continue;
            }
            if self.eof {
                return Ok(false);
            }
            self.next_record()?;
        }
    }

    /// Bytes of the current chunk from `pos` on (in the window or still in the decoder).
    fn remaining(&self) -> u64 {
        (self.chunk.len() - self.pos) as u64 + self.chunk_left
    }

    /// Makes the window hold `n` bytes from `pos` (n at most `IN_MEMORY`), unpacking more of a
    /// streamed chunk; false when the chunk ends first.
    fn fill(&mut self, n: usize) -> bool {
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
    fn skip(&mut self, n: u64) -> bool {
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
    fn peek_u32(&mut self, at: usize) -> Option<u32> {
        self.fill(at + 4)
            .then(|| u32_at(&self.chunk, self.pos + at))?
    }

    /// Drops the rest of the current chunk (its decoder's bytes go back to `raw`).
    fn end_chunk(&mut self) {
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
    fn next_in_chunk(&mut self) {
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
    fn corrupt_chunk(&mut self) {
        if !self.eof {
            self.stats.unknown_words += 1;
        }
        self.end_chunk();
    }

    /// With `pos` at a message's `data_len` bytes of data, all in the chunk: the EventArray's
    /// (width, height, event count) with `pos` moved to its first event, or, when the bytes
    /// are not exactly that layout (see `event_array`), how many of them were passed.
    fn event_array_prefix(&mut self, data_len: u64) -> Result<(u32, u32, usize), u64> {
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

    fn register(&mut self, conn: Option<Connection>) {
        match conn {
            Some(c) => {
                self.wanted.remove(&c.id);
                self.connections.insert(c.id, c);
            }
            None => self.stats.unknown_words += 1,
        }
    }

    fn is_wanted(&mut self, id: u32) -> bool {
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
    fn next_record(&mut self) -> io::Result<()> {
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

    /// The chunk in `raw` (header in `header`) made the current chunk: an uncompressed chunk
    /// the file ends in keeps its complete records; a cut or corrupt compressed one, none.
    /// A compressed chunk is unpacked whole when it fits `IN_MEMORY`, else streamed (see the
    /// module's notes).
    fn unpack_chunk(&mut self, cut: bool) {
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

    /// One top-level record: its header into `header`, its data into `raw` for chunks and
    /// connections (skipped otherwise).
    fn read_record(&mut self) -> io::Result<Read1> {
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

impl<R: Read> EventSource for BagReader<R> {
    fn stats(&self) -> Stats {
        self.stats
    }

    fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        let mut out = growing_chunk(max_events);
        while out.len() < max_events && self.advance()? {
            let in_window = (self.chunk.len() - self.pos) / EVENT;
            if in_window == 0 {
                // A streamed message continues past the window (its length was checked
                // against the chunk's, so only a decoder failing now ends it early).
                if !self.fill(EVENT) {
                    self.pending = 0;
                }
                continue;
            }
            let take = self.pending.min(max_events - out.len()).min(in_window);
            let bytes = &self.chunk[self.pos..self.pos + take * EVENT];
            // Column by column: exact-size iterators extend without a capacity check per event.
            let records = bytes.chunks_exact(EVENT);
            out.x
                .extend(records.clone().map(|r| u16::from_le_bytes([r[0], r[1]])));
            out.y
                .extend(records.clone().map(|r| u16::from_le_bytes([r[2], r[3]])));
            out.t.extend(records.clone().map(|r| {
                let sec = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as i64;
                let nsec = u32::from_le_bytes([r[8], r[9], r[10], r[11]]) as i64;
                sec * 1_000_000 + nsec / 1000
            }));
            out.p.extend(records.map(|r| (r[12] != 0) as i8));
            self.pos += take * EVENT;
            self.pending -= take;
        }
        Ok(out)
    }
}

/// A connection record's id, topic and type (its data is a header of `type`, `md5sum`, ...).
fn connection(header: &[u8], data: &[u8]) -> Option<Connection> {
    Some(Connection {
        id: field_u32(header, b"conn")?,
        topic: field_str(header, b"topic")?,
        msgtype: field_str(data, b"type")?,
    })
}

/// The connections of a bag: from its index (the connection records after the chunks, at the
/// bag header's `index_pos`), or, for a bag without one (its recording was cut off), from a
/// pass through all of its records.
pub fn bag_connections<R: Read + Seek>(mut src: R, block: usize) -> io::Result<Vec<Connection>> {
    let mut reader = BagReader::new(&mut src, None, block)?;
    reader.read_record()?;
    let index_pos = if field(&reader.header, b"op") == Some(&[OP_BAG_HEADER]) {
        field_u64(&reader.header, b"index_pos").unwrap_or(0)
    } else {
        0
    };
    drop(reader);
    let len = src.seek(SeekFrom::End(0))?;
    if index_pos > MAGIC.len() as u64 && index_pos < len {
        src.seek(SeekFrom::Start(index_pos))?;
        let mut index = BagReader::at(&mut src, None, block);
        index.skimming = true;
        while !index.eof {
            index.next_record()?;
        }
        if !index.connections.is_empty() {
            return Ok(index.connections());
        }
    }
    src.seek(SeekFrom::Start(0))?;
    let mut reader = BagReader::new(&mut src, None, block)?;
    reader.skim()?;
    Ok(reader.connections())
}
