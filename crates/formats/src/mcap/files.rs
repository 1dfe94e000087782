//! The MCAP files of one ROS 2 bag, read one after the other through `McapReader`.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{self, Read};
use std::path::{Path, PathBuf};

use super::McapReader;
use crate::unpack;
use crate::{EventSource, Events, Ros2Compression, Stats};

/// A file of a ROS 2 bag, as `McapReader` reads it.
type Source = Box<dyn Read + Send + Sync>;

/// The chosen topic's events in the MCAP files of a ROS 2 bag, maybe split over several
/// (rosbag2 writes each as a whole MCAP file, its schemas and channels included) and maybe
/// compressed by rosbag2 (per message, or per file: a `NAME.mcap.zstd` is unpacked as it is
/// read, MCAP needing no seeking), file after file in the given order, each through
/// `McapReader` (its chunks bounded as in one file); a chunk of events continues into the
/// next file, so only the last one is short. Errors name the file.
pub struct McapFiles {
    /// The files after the current one.
    rest: VecDeque<PathBuf>,
    path: PathBuf,
    current: McapReader<Source>,
    topic: Option<String>,
    compression: Ros2Compression,
    block: usize,
    /// The counts of the files read through.
    done: Stats,
}

impl std::fmt::Debug for McapFiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapFiles")
            .field("path", &self.path)
            .field("rest", &self.rest)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl McapFiles {
    /// A reader of `topic` (None: every event-array channel) in `paths` (compressed as
    /// `compression` says), each through a read buffer of `block` bytes; the first file is
    /// opened here (fails without the magic), each further one when the reading reaches it.
    pub fn new(
        paths: &[PathBuf],
        topic: Option<&str>,
        compression: Ros2Compression,
        block: usize,
    ) -> io::Result<Self> {
        let mut rest: VecDeque<PathBuf> = paths.iter().cloned().collect();
        let path = rest
            .pop_front()
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "no MCAP file to read"))?;
        let current = Self::open(&path, topic, compression, block)?;
        Ok(Self {
            rest,
            path,
            current,
            topic: topic.map(str::to_string),
            compression,
            block,
            done: Stats::default(),
        })
    }

    fn open(
        path: &Path,
        topic: Option<&str>,
        compression: Ros2Compression,
        block: usize,
    ) -> io::Result<McapReader<Source>> {
        let opened = || -> io::Result<McapReader<Source>> {
            let file = File::open(path)?;
            let src: Source = match compression {
                Ros2Compression::File => {
                    // Cut at the cap: a bomb reads as a truncated file, not a full disk or memory.
                    // A file cut short reads up to its last whole record, as a cut .mcap does.
                    let cap = unpack::cap(file.metadata()?.len());
                    let decoder = zstd::stream::read::Decoder::new(file)?;
                    Box::new(unpack::EndsWhereCut(decoder).take(cap))
                }
                _ => Box::new(file),
            };
            let mut reader = McapReader::new(src, topic, block)?;
            if compression == Ros2Compression::Message {
                reader.unpack_messages()?;
            }
            Ok(reader)
        };
        opened().map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", path.display())))
    }

    /// Moves on to the next file (true), or finds none left (false).
    fn next_file(&mut self) -> io::Result<bool> {
        let Some(path) = self.rest.pop_front() else {
            return Ok(false);
        };
        let next = Self::open(&path, self.topic.as_deref(), self.compression, self.block)?;
        self.done += self.current.stats;
        (self.current, self.path) = (next, path);
        Ok(true)
    }

    fn named(&self, e: io::Error) -> io::Error {
        io::Error::new(e.kind(), format!("{}: {e}", self.path.display()))
    }

    /// The (width, height) of the first event message, reading up to it (through files
    /// without one); None when no file has a readable event message.
    pub fn sensor_size(&mut self) -> io::Result<Option<(u32, u32)>> {
        loop {
            if let Some(size) = self.current.sensor_size().map_err(|e| self.named(e))? {
                return Ok(Some(size));
            }
            if !self.next_file()? {
                return Ok(None);
            }
        }
    }
}

impl EventSource for McapFiles {
    fn stats(&self) -> Stats {
        let mut all = self.done;
        all += self.current.stats;
        all
    }

    fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        let mut out = self
            .current
            .next_chunk(max_events)
            .map_err(|e| self.named(e))?;
        // A short chunk is the end of the current file's events.
        while out.len() < max_events && self.next_file()? {
            let more =
                (self.current.next_chunk(max_events - out.len())).map_err(|e| self.named(e))?;
            out.x.extend(more.x);
            out.y.extend(more.y);
            out.t.extend(more.t);
            out.p.extend(more.p);
        }
        Ok(out)
    }
}
