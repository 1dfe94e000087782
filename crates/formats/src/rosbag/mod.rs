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

//!
//! `records` reads the bag's top-level records, `chunk` the records inside a chunk (unpacking
//! it whole or through the window).

use std::collections::HashMap;
use std::io::{self, BufReader, Read, Seek, SeekFrom};

use crate::bytes::u32_at;
use crate::{growing_chunk, EventSource, Events, Stats};

mod chunk;
mod records;

use chunk::Unpack;
use records::read_up_to;

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
