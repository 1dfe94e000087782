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
//! x u16, y u16, ts sec u32, ts nsec u32, polarity u8. Memory is the read buffer plus one
//! chunk (compressed and uncompressed), whatever the bag's length.

use std::collections::HashMap;
use std::io::{self, BufReader, Read, Seek, SeekFrom};

use crate::bytes::u32_at;
use crate::{Events, Stats};

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

/// One record of a byte slice (a decompressed chunk): (header, data, bytes it spans), or None
/// when it runs past the slice's end.
fn record_in(bytes: &[u8]) -> Option<(&[u8], &[u8], usize)> {
    let header_len = u32_at(bytes, 0)? as usize;
    let data_at = 4usize.checked_add(header_len)?.checked_add(4)?;
    let data_len = u32_at(bytes, data_at - 4)? as usize;
    let end = data_at.checked_add(data_len)?;
    let data = bytes.get(data_at..end)?;
    Some((&bytes[4..data_at - 4], data, end))
}

/// Appends up to `n` bytes of `src` to `buf` (fewer only at the end of the input). Nothing is
/// reserved from `n`: the buffer grows with the bytes that come, so a corrupt length costs no
/// more memory than the input holds (the buffers keep their capacity from record to record).
fn read_up_to<R: Read>(src: &mut R, buf: &mut Vec<u8>, n: u64) -> io::Result<u64> {
    Ok(src.take(n).read_to_end(buf)? as u64)
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
#[derive(Debug)]
pub struct BagReader<R> {
    src: BufReader<R>,
    /// The topic to read; None: every connection of an event-array type.
    topic: Option<String>,
    /// Connections only, no events (`skim`).
    skimming: bool,
    header: Vec<u8>,
    raw: Vec<u8>,
    /// The current chunk's records (uncompressed) and the position of the next one.
    chunk: Vec<u8>,
    pos: usize,
    /// The message being emitted: (offset of its next event in `chunk`, events left).
    pending: Option<(usize, usize)>,
    connections: HashMap<u32, Connection>,
    wanted: HashMap<u32, bool>,
    size: Option<(u32, u32)>,
    largest_chunk: usize,
    unpacked: u64,
    eof: bool,
    stats: Stats,
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
            pending: None,
            connections: HashMap::new(),
            wanted: HashMap::new(),
            size: None,
            largest_chunk: 0,
            unpacked: 0,
            eof: false,
            stats: Stats::default(),
        }
    }

    /// What was read but not turned into events so far (complete once a chunk came back empty).
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// The connections seen so far, by id.
    pub fn connections(&self) -> Vec<Connection> {
        let mut all: Vec<_> = self.connections.values().cloned().collect();
        all.sort_by_key(|c| c.id);
        all
    }

    /// The capacities of the reader's record buffers (header, data, unpacked chunk), the most
    /// bytes one chunk unpacked to and the bytes all chunks unpacked to so far: the fuzzers
    /// bound the buffers by the input and the largest chunk, the events by the total.
    pub fn buffers(&self) -> ([usize; 3], usize, u64) {
        let caps = [
            self.header.capacity(),
            self.raw.capacity(),
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

    /// The next chunk: `max_events` events (at least 1), fewer only at the end of the input,
    /// where it is empty.
    pub fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        // Grown by doubling from a small start: a small bag allocates little.
        let mut out = Events::with_capacity(max_events.min(1 << 16));
        while out.len() < max_events && self.advance()? {
            let Some((at, left)) = self.pending else {
                continue;
            };
            let take = left.min(max_events - out.len());
            let bytes = &self.chunk[at..at + take * EVENT];
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
            self.pending = (take < left).then_some((at + take * EVENT, left - take));
        }
        Ok(out)
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
            if matches!(self.pending, Some((_, left)) if left > 0) {
                return Ok(true);
            }
            self.pending = None;
            if self.pos < self.chunk.len() {
                self.next_in_chunk();
                continue;
            }
            if self.eof {
                return Ok(false);
            }
            self.next_record()?;
        }
    }

    /// The record at `pos` in the current chunk.
    fn next_in_chunk(&mut self) {
        let Some((header, data, len)) = record_in(&self.chunk[self.pos..]) else {
            // A record cut by the chunk's end: a corrupt chunk, or one the file ends in (whose
            // bytes `truncated_bytes` already counts).
            if !self.eof {
                self.stats.unknown_words += 1;
            }
            self.pos = self.chunk.len();
            return;
        };
        let at = self.pos;
        self.pos += len;
        let data_at = at + len - data.len();
        match field(header, b"op").and_then(|op| op.first().copied()) {
            Some(OP_CONNECTION) => {
                let conn = connection(header, data);
                self.register(conn);
            }
            Some(OP_MESSAGE) => {
                let id = field_u32(header, b"conn");
                let array = event_array(data);
                if !id.is_some_and(|id| self.is_wanted(id)) {
                    return;
                }
                match array {
                    Some((width, height, start, n)) => {
                        self.size.get_or_insert((width, height));
                        self.pending = Some((data_at + start, n));
                    }
                    None => self.stats.unknown_words += 1,
                }
            }
            _ => {}
        }
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
        self.chunk.clear();
        self.pos = 0;
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

    /// The chunk in `raw` (header in `header`) decompressed into `chunk`: an uncompressed chunk
    /// the file ends in keeps its complete records; a cut or corrupt compressed one, none.
    fn unpack_chunk(&mut self, cut: bool) {
        let size = field_u32(&self.header, b"size").unwrap_or(0) as u64;
        let decoded = match field(&self.header, b"compression") {
            Some(b"none") => {
                std::mem::swap(&mut self.chunk, &mut self.raw);
                Ok(())
            }
            Some(b"lz4") => {
                let mut dec = lz4_flex::frame::FrameDecoder::new(&self.raw[..]);
                read_up_to(&mut dec, &mut self.chunk, size).map(|_| ())
            }
            Some(b"bz2") => {
                let mut dec = bzip2::read::BzDecoder::new(&self.raw[..]);
                read_up_to(&mut dec, &mut self.chunk, size).map(|_| ())
            }
            _ => Err(io::Error::other("unknown compression")),
        };
        self.largest_chunk = self.largest_chunk.max(self.chunk.len());
        let compressed = field(&self.header, b"compression") != Some(b"none");
        if compressed && (decoded.is_err() || cut) {
            // A compressed chunk is all or nothing: a decoder's output from damaged input
            // depends on where its reads stop, so none of it is kept.
            self.chunk.clear();
        }
        if decoded.is_err() && !cut {
            self.stats.unknown_words += 1;
        }
        self.unpacked += self.chunk.len() as u64;
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
