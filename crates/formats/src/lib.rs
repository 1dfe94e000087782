//! Decoders of event-camera recordings: the binary words of Prophesee EVT 2.0, EVT 3.0 and DAT
//! (CD events), the event-array messages of ROS 1 bags (`rosbag`), of ROS 2 bags in MCAP
//! (`mcap`) and in SQLite (`db3`), split over several files or zstd-compressed by rosbag2 (per
//! message or per file), and the event packets of AEDAT 4 files (`aedat4`), turned into events,
//! chunk by chunk. Each decoder keeps its state (time base, row, vector base) across calls, so
//! a recording streams through a bounded buffer; every compressed block unpacks within a bound
//! (`unpack`). Headers are parsed by the Python reader (python/evsplat/data/formats/
//! prophesee.py); this crate sees the bytes after them. On the way out, `blosc` compresses the
//! HDF5 event file's chunks as the HDF5 Blosc filter does.

pub mod aedat4;
pub mod blosc;
mod bytes;
mod cdr;
#[cfg(any(test, feature = "check"))]
pub mod check;
pub mod dat;
pub mod db3;
pub mod evt2;
pub mod evt3;
pub mod mcap;
mod reader;
pub mod rosbag;
mod unpack;

pub use reader::{ChunkReader, Encoding};

pub use evsplat_events::Events;

/// Room an events buffer starts with before it grows (by doubling): a chunk of a small or
/// corrupt recording allocates little, whatever size was asked for.
const FIRST_ROOM: usize = 1 << 16;

/// An empty chunk that will take at most `max_events` events, with room for up to
/// `FIRST_ROOM` of them.
pub(crate) fn growing_chunk(max_events: usize) -> Events {
    Events::with_capacity(max_events.min(FIRST_ROOM))
}

/// A recording's events, chunk by chunk: every format's reader (`ChunkReader` for the EVT and
/// DAT words, `rosbag::BagReader`, `mcap::McapReader` and `mcap::McapFiles`, `db3::Db3Reader`,
/// `aedat4::AedatReader`).
pub trait EventSource {
    /// What was read but not turned into events so far (complete once a chunk came back
    /// empty).
    fn stats(&self) -> Stats;

    /// The next chunk of at most `max_events` events (at least 1), fewer only at the end of
    /// the recording, where it is empty.
    fn next_chunk(&mut self, max_events: usize) -> std::io::Result<Events>;
}

/// How rosbag2 compressed a ROS 2 bag's files (.db3 or MCAP; metadata.yaml's
/// `compression_mode`, with `compression_format` zstd, the only format rosbag2 writes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ros2Compression {
    None,
    /// Each message's data is a zstd frame.
    Message,
    /// Each file is one zstd stream of the whole file (`NAME.db3.zstd`, `NAME.mcap.zstd`).
    File,
}

impl Ros2Compression {
    /// The mode as metadata.yaml spells it ("" or "none", "message", "file").
    pub fn from_mode(mode: &str) -> Option<Self> {
        match mode {
            "" | "none" => Some(Self::None),
            "message" => Some(Self::Message),
            "file" => Some(Self::File),
            _ => None,
        }
    }
}

/// What a decoder read but did not turn into events.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Stats {
    /// CD events before the stream's first time base (no timestamp to give them).
    pub untimed_events: u64,
    /// Words of a type the format does not define (skipped).
    pub unknown_words: u64,
    /// Bytes after the last complete word or record (a truncated file).
    pub truncated_bytes: u64,
}

impl std::ops::AddAssign for Stats {
    fn add_assign(&mut self, other: Self) {
        self.untimed_events += other.untimed_events;
        self.unknown_words += other.unknown_words;
        self.truncated_bytes += other.truncated_bytes;
    }
}

/// One format's word decoder: the state carried from one call to the next.
pub trait Decode {
    /// Bytes per word (EVT) or record (DAT).
    const WORD: usize;
    /// Most events one word can produce.
    const MAX_PER_WORD: usize;

    /// Decodes whole words from the start of `bytes` into `out` until `out` holds
    /// `max_events` (a word's events past it wait for the next call); returns the bytes
    /// consumed, a multiple of `WORD`.
    fn decode(
        &mut self,
        bytes: &[u8],
        out: &mut Events,
        max_events: usize,
        stats: &mut Stats,
    ) -> usize;
}

/// A counter that wraps: `value` read after `last`, unwrapped into `loops` periods of
/// `1 << bits`. A drop of at least `min_drop` is the counter wrapping; a smaller drop is a
/// step back in time, kept as it is (the caller's validation reports it).
#[derive(Debug, Default, Clone, Copy)]
struct Unwrap {
    last: Option<u64>,
    loops: u64,
}

impl Unwrap {
    #[inline]
    fn next(&mut self, value: u64, bits: u32, min_drop: u64) -> u64 {
        if let Some(last) = self.last {
            if last >= value + min_drop {
                self.loops += 1;
            }
        }
        self.last = Some(value);
        (self.loops << bits) | value
    }
}

#[cfg(test)]
mod fuzz_tests;
#[cfg(test)]
mod tests;
