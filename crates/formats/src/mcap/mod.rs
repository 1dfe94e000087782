//! MCAP files of ROS 2 bags: the event arrays of one topic (`dvs_msgs/msg/EventArray`,
//! `prophesee_event_msgs/msg/EventArray`, CDR-encoded), read record by record and returned in
//! chunks of events.
//!
//! A file is the magic `\x89MCAP0\r\n` and then records: an op byte, a u64 length and the
//! content. Strings are a u32 length and the bytes. Schemas (0x03: id u16, name, encoding,
//! data) name the message types; channels (0x04: id u16, schema id u16, topic, message
//! encoding, metadata) the topics; messages (0x05: channel id u16, sequence u32, log and
//! publish times u64, then the data) carry them; chunks (0x06: start and end times, the
//! uncompressed size u64 and CRC u32, compression "", "zstd" or "lz4", then the records as a
//! u64-length byte array) hold schemas, channels and messages. The data section ends at
//! DataEnd (0x0F) or the footer (0x02); the summary after it repeats the schemas and channels.
//! The reader goes through the records in file order and needs no summary, so a file whose
//! recording was cut off reads up to its last complete chunk.
//!
//! The messages' CDR EventArray layout is `cdr`'s (shared with the .db3 reader).
//!
//! `files` reads a bag's MCAP files one after the other (split, or compressed by rosbag2).

use std::collections::HashMap;
use std::io::{self, BufReader, Read, Seek, SeekFrom};

use crate::bytes::{u16_at, u32_at, u64_at};
use crate::unpack::{self, Frames};
use crate::{growing_chunk, EventSource, Events, Stats};

mod files;

pub use files::McapFiles;

/// The first (and last) 8 bytes of every MCAP file.
pub const MAGIC: &[u8] = b"\x89MCAP0\r\n";
/// The event-array message types (schema names).
pub const EVENT_TYPES: [&str; 2] = [
    "dvs_msgs/msg/EventArray",
    "prophesee_event_msgs/msg/EventArray",
];
pub use crate::cdr::{event_array, EVENT};

const OP_FOOTER: u8 = 0x02;
const OP_SCHEMA: u8 = 0x03;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;
const OP_CHUNK: u8 = 0x06;
const OP_DATA_END: u8 = 0x0F;

/// A topic's channel: its id, topic and message type (its schema's name).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channel {
    pub id: u16,
    pub topic: String,
    pub msgtype: String,
}

/// The string at `at` and the position after it.
fn string_at(b: &[u8], at: usize) -> Option<(&[u8], usize)> {
    let len = u32_at(b, at)? as usize;
    let end = (at + 4).checked_add(len)?;
    Some((b.get(at + 4..end)?, end))
}

/// One record of a byte slice: (op, content, bytes it spans), or None when it runs past the
/// slice's end.
fn record_in(b: &[u8]) -> Option<(u8, &[u8], usize)> {
    let op = *b.first()?;
    let len = usize::try_from(u64_at(b, 1)?).ok()?;
    let end = 9usize.checked_add(len)?;
    Some((op, b.get(9..end)?, end))
}

/// The events of the chosen topic's EventArray messages, in file order, in chunks of at most
/// `max_events`; `stats()`: `unknown_words` counts records that are not what their op says
/// (event messages of another layout, corrupt or unknown-compression chunks),
/// `truncated_bytes` the bytes of a last record the file ends in.
#[derive(Debug)]
pub struct McapReader<R> {
    src: BufReader<R>,
    /// The topic to read; None: every channel of an event-array type.
    topic: Option<String>,
    skimming: bool,
    raw: Vec<u8>,
    /// The current chunk's records (uncompressed, or one top-level record) and the position of
    /// the next one.
    chunk: Vec<u8>,
    pos: usize,
    /// The message being emitted: (offset of its first event in `chunk`, count, next index).
    pending: Option<(usize, usize, usize)>,
    schemas: HashMap<u16, String>,
    channels: HashMap<u16, (u16, String)>,
    wanted: HashMap<u16, bool>,
    size: Option<(u32, u32)>,
    largest: usize,
    /// The unpacker of a message-compressed bag's messages (`unpack_messages`).
    frames: Option<Frames>,
    unpacked: u64,
    eof: bool,
    stats: Stats,
}

impl<R: Read> McapReader<R> {
    /// A reader of `src` (at the start of the file) for `topic` (None: every event-array
    /// channel), through a read buffer of `block` bytes. Fails without the magic.
    pub fn new(src: R, topic: Option<&str>, block: usize) -> io::Result<Self> {
        let mut reader = Self::at(src, topic, block);
        let mut magic = Vec::new();
        (&mut reader.src).take(8).read_to_end(&mut magic)?;
        if magic != MAGIC {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "not MCAP: it does not start with the MCAP magic (a .db3 ROS 2 bag is SQLite)",
            ));
        }
        Ok(reader)
    }

    fn at(src: R, topic: Option<&str>, block: usize) -> Self {
        Self {
            src: BufReader::with_capacity(block.max(1), src),
            topic: topic.map(str::to_string),
            skimming: false,
            raw: Vec::new(),
            chunk: Vec::new(),
            pos: 0,
            pending: None,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            wanted: HashMap::new(),
            size: None,
            largest: 0,
            frames: None,
            unpacked: 0,
            eof: false,
            stats: Stats::default(),
        }
    }

    /// Unpacks each message's data as a zstd frame first (a bag rosbag2 compressed per
    /// message); a frame that does not unpack is a record counted in `unknown_words`.
    pub fn unpack_messages(&mut self) -> io::Result<()> {
        self.frames = Some(Frames::new()?);
        Ok(())
    }

    /// The channels seen so far, by id (type "?" while its schema is unseen).
    pub fn channels(&self) -> Vec<Channel> {
        let mut all: Vec<_> = (self.channels.iter())
            .map(|(&id, (schema, topic))| Channel {
                id,
                topic: topic.clone(),
                msgtype: self
                    .schemas
                    .get(schema)
                    .cloned()
                    .unwrap_or_else(|| "?".into()),
            })
            .collect();
        all.sort_by_key(|c| c.id);
        all
    }

    /// The capacities of the record buffers (read, unpacked), the most bytes one chunk
    /// unpacked to and the bytes all unpacked to so far (the fuzzers' bounds).
    pub fn buffers(&self) -> ([usize; 2], usize, u64) {
        (
            [self.raw.capacity(), self.chunk.capacity()],
            self.largest,
            self.unpacked,
        )
    }

    /// The (width, height) of the first event message, reading up to it; None when the topic
    /// has no readable event message.
    pub fn sensor_size(&mut self) -> io::Result<Option<(u32, u32)>> {
        while self.size.is_none() && self.advance()? {}
        Ok(self.size)
    }

    /// Reads through the data section, registering schemas and channels; no events.
    pub fn skim(&mut self) -> io::Result<()> {
        self.skimming = true;
        self.wanted.clear();
        while self.advance()? {}
        Ok(())
    }

    /// Steps until a message with events left is pending (true) or the data ends (false).
    fn advance(&mut self) -> io::Result<bool> {
        loop {
            if self.pending.is_some() {
                return Ok(true);
            }
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
        let Some((op, content, len)) = record_in(&self.chunk[self.pos..]) else {
            if !self.eof {
                self.stats.unknown_words += 1;
            }
            self.pos = self.chunk.len();
            return;
        };
        let content_at = self.pos + 9;
        self.pos += len;
        match op {
            OP_SCHEMA => match (u16_at(content, 0), string_at(content, 2)) {
                (Some(id), Some((name, _))) => {
                    let name = String::from_utf8_lossy(name).into_owned();
                    self.schemas.insert(id, name);
                    self.wanted.clear();
                }
                _ => self.stats.unknown_words += 1,
            },
            OP_CHANNEL => match (
                u16_at(content, 0),
                u16_at(content, 2),
                string_at(content, 4),
            ) {
                (Some(id), Some(schema), Some((topic, _))) => {
                    let topic = String::from_utf8_lossy(topic).into_owned();
                    self.channels.insert(id, (schema, topic));
                    self.wanted.remove(&id);
                }
                _ => self.stats.unknown_words += 1,
            },
            OP_MESSAGE => {
                let end = self.pos;
                if !u16_at(content, 0).is_some_and(|id| self.is_wanted(id)) {
                    return;
                }
                let data = self.chunk.get(content_at + 22..end).unwrap_or_default();
                // A message-compressed bag's data is a zstd frame, unpacked into `frames`
                // (pending then points into it).
                let (array, base) = match &mut self.frames {
                    Some(frames) => (frames.unpack(data).ok().and_then(event_array), 0),
                    None => (event_array(data), content_at + 22),
                };
                match array {
                    Some((width, height, start, n)) => {
                        self.size.get_or_insert((width, height));
                        if n > 0 {
                            self.pending = Some((base + start, n, 0));
                        }
                    }
                    None => self.stats.unknown_words += 1,
                }
            }
            _ => {}
        }
    }

    fn is_wanted(&mut self, id: u16) -> bool {
        if let Some(&w) = self.wanted.get(&id) {
            return w;
        }
        let w = !self.skimming
            && self.channels.get(&id).is_some_and(|(schema, topic)| {
                self.schemas
                    .get(schema)
                    .is_some_and(|name| EVENT_TYPES.contains(&name.as_str()))
                    && self.topic.as_deref().is_none_or(|t| t == topic)
            });
        self.wanted.insert(id, w);
        w
    }

    /// Reads the next top-level record: a chunk's records, or a schema, channel or message
    /// itself, become the current chunk; the end of the data section ends the reading.
    fn next_record(&mut self) -> io::Result<()> {
        self.chunk.clear();
        self.pos = 0;
        self.raw.clear();
        let got = (&mut self.src).take(9).read_to_end(&mut self.raw)? as u64;
        if got < 9 {
            self.eof = true;
            self.stats.truncated_bytes += got;
            return Ok(());
        }
        let op = self.raw[0];
        let len = u64::from_le_bytes(self.raw[1..9].try_into().unwrap_or([0; 8]));
        if matches!(op, OP_FOOTER | OP_DATA_END) {
            self.eof = true;
            return Ok(());
        }
        let keep = matches!(op, OP_CHUNK | OP_SCHEMA | OP_CHANNEL | OP_MESSAGE);
        let got = if keep {
            (&mut self.src).take(len).read_to_end(&mut self.raw)? as u64
        } else {
            io::copy(&mut (&mut self.src).take(len), &mut io::sink())?
        };
        if got < len {
            // A record the file ends in: dropped whole (a chunk is all or nothing).
            self.eof = true;
            self.stats.truncated_bytes += 9 + got;
            return Ok(());
        }
        match op {
            OP_CHUNK => self.unpack_chunk(),
            OP_SCHEMA | OP_CHANNEL | OP_MESSAGE => std::mem::swap(&mut self.chunk, &mut self.raw),
            _ => {}
        }
        Ok(())
    }

    /// The chunk record in `raw` (its 9-byte framing first) unpacked into `chunk`.
    fn unpack_chunk(&mut self) {
        let c = &self.raw[9..];
        let size = u64_at(c, 16);
        let compression = string_at(c, 28);
        let records = compression.and_then(|(_, at)| {
            let len = usize::try_from(u64_at(c, at)?).ok()?;
            c.get(at + 8..(at + 8).checked_add(len)?)
        });
        let (Some(size), Some((compression, _)), Some(records)) = (size, compression, records)
        else {
            self.stats.unknown_words += 1;
            return;
        };
        // Past its declared size's own check: a larger output is a decompression bomb.
        let cap = size.min(unpack::cap(records.len() as u64));
        let unpacked = match compression {
            b"" => {
                self.chunk.extend_from_slice(records);
                Ok(())
            }
            b"zstd" => zstd::stream::read::Decoder::with_buffer(records)
                .and_then(|dec| dec.take(cap).read_to_end(&mut self.chunk).map(|_| ())),
            b"lz4" => lz4_flex::frame::FrameDecoder::new(records)
                .take(cap)
                .read_to_end(&mut self.chunk)
                .map(|_| ()),
            _ => Err(io::Error::other("unknown compression")),
        };
        self.largest = self.largest.max(self.chunk.len());
        if unpacked.is_err() || self.chunk.len() as u64 != size {
            self.chunk.clear();
            self.stats.unknown_words += 1;
        }
        self.unpacked += self.chunk.len() as u64;
    }
}

impl<R: Read> EventSource for McapReader<R> {
    fn stats(&self) -> Stats {
        self.stats
    }

    fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        let mut out = growing_chunk(max_events);
        while out.len() < max_events && self.advance()? {
            let Some((start, n, next)) = self.pending else {
                continue;
            };
            let take = (n - next).min(max_events - out.len());
            let data = self.frames.as_ref().map_or(&self.chunk[..], Frames::out);
            crate::cdr::push_events(data, start, next, take, &mut out);
            let next = next + take;
            self.pending = (next < n).then_some((start, n, next));
        }
        Ok(out)
    }
}

/// The channels of an MCAP file: from its summary (the footer's `summary_start`), or, for a
/// file without one (its recording was cut off), from a pass through its data section.
pub fn mcap_channels<R: Read + Seek>(mut src: R, block: usize) -> io::Result<Vec<Channel>> {
    McapReader::new(&mut src, None, block)?;
    let len = src.seek(SeekFrom::End(0))?;
    // The footer: op, length 20, summary_start u64, summary_offset_start u64, CRC u32; magic.
    if len >= 8 + 29 + 8 {
        src.seek(SeekFrom::Start(len - 8 - 29))?;
        let mut tail = Vec::new();
        (&mut src).take(29 + 8).read_to_end(&mut tail)?;
        let summary = u64_at(&tail, 9).filter(|&s| tail[0] == OP_FOOTER && s > 8 && s < len);
        if let Some(start) = summary {
            src.seek(SeekFrom::Start(start))?;
            let mut index = McapReader::at(&mut src, None, block);
            index.skim()?;
            if !index.channels.is_empty() {
                return Ok(index.channels());
            }
        }
    }
    src.seek(SeekFrom::Start(0))?;
    let mut reader = McapReader::new(&mut src, None, block)?;
    reader.skim()?;
    Ok(reader.channels())
}
