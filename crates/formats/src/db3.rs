//! ROS 2 bags stored in SQLite (`.db3`, rosbag2's default storage up to ROS 2 Iron): the
//! CDR event arrays of one topic (layout: `cdr`), in timestamp order, returned in chunks of
//! events.
//!
//! A .db3 file has a `topics` table (id, name, type, ...) and a `messages` table (id,
//! topic_id, timestamp, data), with an index on the timestamp. One query joins the two and
//! reads the chosen topic's messages ordered by timestamp (then id, the order rosbags gives
//! ties), row by row, in a thread of its own that decodes each message's events straight from
//! SQLite's row into chunks and hands them over through a channel of one chunk: memory is a
//! few chunks whatever the bag's size, and SQLite's reading and the decoding overlap the
//! caller's work on the chunk before (`evsplat convert`'s HDF5 writes). A bag split over
//! several files is read file after file, as rosbags does. SQLite's errors (a file that is
//! not a database, truncated, damaged) end the reading with an error naming the file.
//!
//! rosbag2 compresses a bag with zstd in one of two modes (metadata.yaml's
//! `compression_mode`): "message", each message's data one zstd frame, unpacked row by row
//! into a buffer (bounded by `unpack::cap`); or "file", each file `NAME.db3.zstd`, one zstd
//! stream of the whole .db3. SQLite reads only a file on disk, so such a file is unpacked,
//! streaming, into a temporary .db3 in the system's temp folder, read, and removed before the
//! next: one unpacked file on disk at a time, removed also when the reading fails or stops
//! (only a killed process leaves it, `evsplat-PID-N.db3`, behind).

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::Mutex;

use rusqlite::{Connection, OpenFlags};

use crate::cdr::{event_array, push_events};
use crate::unpack::{self, Frames};
use crate::{growing_chunk, EventSource, Events, Ros2Compression, Stats};

/// A topic of a .db3 file: its id, name and message type (`pkg/msg/Name`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topic {
    pub id: i64,
    pub name: String,
    pub msgtype: String,
}

fn sql_error(path: &Path, e: rusqlite::Error) -> io::Error {
    let what = e.to_string().replace('\n', " ");
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("{}: SQLite: {what}", path.display()),
    )
}

/// A read-only, immutable connection (no lock, no journal: the bag is not being written).
fn open(path: &Path) -> rusqlite::Result<Connection> {
    // A URI, so that `immutable` applies; '%', '?' and '#' of the path are escaped.
    let mut uri = String::from("file:");
    for c in path.to_string_lossy().chars() {
        match c {
            '%' => uri.push_str("%25"),
            '?' => uri.push_str("%3f"),
            '#' => uri.push_str("%23"),
            c => uri.push(c),
        }
    }
    uri.push_str("?immutable=1");
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY
        | OpenFlags::SQLITE_OPEN_URI
        | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    Connection::open_with_flags(uri, flags)
}

/// The topics of a .db3 file, by id.
pub fn db3_topics(path: &Path) -> io::Result<Vec<Topic>> {
    let list = || -> rusqlite::Result<Vec<Topic>> {
        let conn = open(path)?;
        let mut stmt = conn.prepare("SELECT id, name, type FROM topics ORDER BY id")?;
        let rows = stmt.query_map([], |row| {
            Ok(Topic {
                id: row.get(0)?,
                name: row.get(1)?,
                msgtype: row.get(2)?,
            })
        })?;
        rows.collect()
    };
    list().map_err(|e| sql_error(path, e))
}

/// What the SQLite thread hands over: a chunk of events, the sensor size of the first event
/// message so far and the messages of another layout so far; or the error that ended it.
struct Batch {
    events: Events,
    size: Option<(u32, u32)>,
    unknown: u64,
}

type Sent = Result<Batch, io::Error>;

/// Decodes the events of `topic`'s messages in each file, in timestamp order, into chunks of
/// `chunk` events, until the receiver is dropped or a file fails; the last batch (possibly
/// empty) carries the final counts.
fn send_events(
    paths: &[PathBuf],
    topic: &str,
    compression: Ros2Compression,
    chunk: usize,
    tx: &SyncSender<Sent>,
) {
    let mut batch = Batch {
        events: growing_chunk(chunk),
        size: None,
        unknown: 0,
    };
    let mut frames = match Frames::new() {
        Ok(frames) => frames,
        Err(e) => {
            let _ = tx.send(Err(e));
            return;
        }
    };
    for path in paths {
        let file = FileRead {
            path,
            topic,
            compression,
            chunk,
        };
        match file.send(&mut batch, &mut frames, tx) {
            Ok(true) => {}
            Ok(false) => return,
            Err(e) => {
                let _ = tx.send(Err(e));
                return;
            }
        }
    }
    let _ = tx.send(Ok(batch));
}

/// One file of the bag being read.
struct FileRead<'a> {
    path: &'a Path,
    topic: &'a str,
    compression: Ros2Compression,
    chunk: usize,
}

impl FileRead<'_> {
    /// Sends the full chunks of the topic's events in this file, the rest staying in `batch`
    /// (`frames` unpacks compressed messages); false once the receiver is gone.
    fn send(
        &self,
        batch: &mut Batch,
        frames: &mut Frames,
        tx: &SyncSender<Sent>,
    ) -> io::Result<bool> {
        let sql = |e| sql_error(self.path, e);
        let temp = match self.compression {
            Ros2Compression::File => Some(unpack_file(self.path)?),
            _ => None,
        };
        let db = temp.as_ref().map_or(self.path, |t| &t.0);
        let conn = open(db).map_err(sql)?;
        // Pages through a memory map, not a read() call per 4 KiB page (the bundled SQLite
        // caps it at 2 GiB of the file; the rest is read as usual).
        (conn.query_row("PRAGMA mmap_size = 1099511627776", [], |_| Ok(()))).map_err(sql)?;
        // CROSS JOIN keeps `messages` the outer loop, so the timestamp index gives the
        // order (no sort of the whole table) and a topic is looked up by its key.
        let mut stmt = (conn.prepare(
            "SELECT m.data FROM messages AS m CROSS JOIN topics AS t ON m.topic_id = t.id \
             WHERE t.name = ?1 ORDER BY m.timestamp, m.id",
        ))
        .map_err(sql)?;
        let mut rows = stmt.query([self.topic]).map_err(sql)?;
        let mut index = 0u64;
        while let Some(row) = rows.next().map_err(sql)? {
            index += 1;
            let blob = row.get_ref(0).map_err(sql)?.as_blob().unwrap_or_default();
            let data = match self.compression {
                Ros2Compression::Message => frames.unpack(blob).map_err(|e| {
                    let (path, topic) = (self.path.display(), self.topic);
                    let what = format!("{path}: message {index} of {topic}: zstd: {e}");
                    io::Error::new(io::ErrorKind::InvalidData, what)
                })?,
                _ => blob,
            };
            let Some((width, height, start, n)) = event_array(data) else {
                batch.unknown += 1;
                continue;
            };
            batch.size.get_or_insert((width, height));
            let mut next = 0;
            while next < n {
                let take = (n - next).min(self.chunk - batch.events.len());
                push_events(data, start, next, take, &mut batch.events);
                next += take;
                if batch.events.len() == self.chunk {
                    // Full chunks from now on: allocated at their size, not grown.
                    let events =
                        std::mem::replace(&mut batch.events, Events::with_capacity(self.chunk));
                    let full = Batch { events, ..*batch };
                    if tx.send(Ok(full)).is_err() {
                        return Ok(false);
                    }
                }
            }
        }
        Ok(true)
    }
}

/// A file in the system's temp folder, removed when dropped.
struct TempFile(PathBuf);

impl TempFile {
    /// A new, empty file (readable by its owner only), and its handle for writing.
    fn create() -> io::Result<(Self, File)> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        loop {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let name = format!("evsplat-{}-{n}.db3", std::process::id());
            let path = std::env::temp_dir().join(name);
            let mut options = OpenOptions::new();
            options.write(true).create_new(true);
            #[cfg(unix)]
            std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
            match options.open(&path) {
                Ok(file) => return Ok((Self(path), file)),
                // Left by an earlier process of the same id: the next name.
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(e),
            }
        }
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The zstd stream `path` (a `NAME.db3.zstd`) unpacked into a temporary .db3, streaming
/// (memory: the decoder's window and a write buffer), within `unpack::cap` of its size.
fn unpack_file(path: &Path) -> io::Result<TempFile> {
    let named = |what: &str, e: io::Error| {
        let msg = format!("{}: {what}: {e}", path.display());
        io::Error::new(e.kind(), msg)
    };
    let src = File::open(path).map_err(|e| named("cannot open it", e))?;
    let size = src
        .metadata()
        .map_err(|e| named("cannot open it", e))?
        .len();
    let (temp, file) = TempFile::create().map_err(|e| named("no temporary file", e))?;
    // Errors of the unpacking or the writing (a full disk) both say where it went.
    let into = format!("zstd, unpacking into {}", temp.0.display());
    let mut out = BufWriter::with_capacity(1 << 20, file);
    let unpacked = zstd::stream::read::Decoder::new(src)
        .and_then(|dec| unpack::bounded(dec, size, |d| io::copy(d, &mut out)))
        .and_then(|_| out.flush());
    unpacked.map_err(|e| named(&into, e))?;
    Ok(temp)
}

/// The events of a topic's EventArray messages in one or more .db3 files (a split bag), in
/// chunks of at most `max_events`; `stats().unknown_words` counts messages of another layout.
pub struct Db3Reader {
    /// In a mutex only to make the reader `Sync` (Python objects may move between threads);
    /// one reader takes chunks at a time, so it is never contended.
    rx: Mutex<Receiver<Sent>>,
    /// The chunk being handed out and how much of it was.
    current: Events,
    at: usize,
    size: Option<(u32, u32)>,
    done: bool,
    stats: Stats,
}

impl std::fmt::Debug for Db3Reader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Db3Reader")
            .field("at", &self.at)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl Db3Reader {
    /// A reader of `topic` in `paths` (read in that order; compressed as `compression`
    /// says), its thread decoding chunks of `chunk` events (`next_chunk` of that size hands
    /// them over without a copy). A file that cannot be opened as a bag (not SQLite, no
    /// `messages` or `topics` table) fails here; a compressed file, once unpacked, in the
    /// thread.
    pub fn new(
        paths: &[PathBuf],
        topic: &str,
        compression: Ros2Compression,
        chunk: usize,
    ) -> io::Result<Self> {
        // A compressed file's SQLite is checked once the thread has unpacked it.
        if compression != Ros2Compression::File {
            for path in paths {
                let check = || -> rusqlite::Result<()> {
                    let conn = open(path)?;
                    conn.prepare(
                        "SELECT m.topic_id, m.timestamp, m.data FROM messages AS m LIMIT 0",
                    )?;
                    conn.prepare("SELECT t.id, t.name, t.type FROM topics AS t LIMIT 0")?;
                    Ok(())
                };
                check().map_err(|e| sql_error(path, e))?;
            }
        }
        let (tx, rx) = sync_channel(1);
        let (paths, topic, chunk) = (paths.to_vec(), topic.to_string(), chunk.max(1));
        // Not joined: a reader dropped early (its channel closed) must not wait, the GIL held,
        // for the thread's query to reach its next row; the thread ends at its next send.
        std::thread::Builder::new()
            .name("evsplat-db3".into())
            .spawn(move || send_events(&paths, &topic, compression, chunk, &tx))?;
        Ok(Self {
            rx: Mutex::new(rx),
            current: Events::default(),
            at: 0,
            size: None,
            done: false,
            stats: Stats::default(),
        })
    }

    /// The (width, height) of the first event message, reading up to it; None when the topic
    /// has no readable event message.
    pub fn sensor_size(&mut self) -> io::Result<Option<(u32, u32)>> {
        while self.size.is_none() && self.receive()? {}
        Ok(self.size)
    }

    /// Takes the thread's next chunk (true), or finds it ended (false).
    fn receive(&mut self) -> io::Result<bool> {
        if self.done {
            return Ok(false);
        }
        let received = match self.rx.get_mut() {
            Ok(rx) => rx.recv(),
            Err(poisoned) => poisoned.into_inner().recv(),
        };
        match received {
            Ok(Ok(batch)) => {
                self.size = self.size.or(batch.size);
                self.stats.unknown_words = batch.unknown;
                self.current = batch.events;
                self.at = 0;
                Ok(true)
            }
            Ok(Err(e)) => {
                self.done = true;
                Err(e)
            }
            // The thread sent its last chunk and ended.
            Err(_) => {
                self.done = true;
                Ok(false)
            }
        }
    }
}

impl EventSource for Db3Reader {
    fn stats(&self) -> Stats {
        self.stats
    }

    fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        let mut out = Events::default();
        while out.len() < max_events {
            let (at, left) = (self.at, self.current.len() - self.at);
            if left == 0 {
                if !self.receive()? {
                    break;
                }
                continue;
            }
            let take = left.min(max_events - out.len());
            if at == 0 && take == left && out.is_empty() {
                // The whole chunk, as the thread made it.
                out = std::mem::take(&mut self.current);
                self.at = 0;
                continue;
            }
            let c = &self.current;
            out.x.extend_from_slice(&c.x[at..at + take]);
            out.y.extend_from_slice(&c.y[at..at + take]);
            out.t.extend_from_slice(&c.t[at..at + take]);
            out.p.extend_from_slice(&c.p[at..at + take]);
            self.at += take;
        }
        Ok(out)
    }
}
