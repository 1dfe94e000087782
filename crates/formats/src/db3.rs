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

use std::io;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::Mutex;

use rusqlite::{Connection, OpenFlags};

use crate::cdr::{event_array, push_events};
use crate::{EventSource, Events, Stats};

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
fn send_events(paths: &[PathBuf], topic: &str, chunk: usize, tx: &SyncSender<Sent>) {
    let mut batch = Batch {
        events: Events::with_capacity(chunk.min(1 << 16)),
        size: None,
        unknown: 0,
    };
    for path in paths {
        let mut read = || -> rusqlite::Result<bool> {
            let conn = open(path)?;
            // Pages through a memory map, not a read() call per 4 KiB page (the bundled SQLite
            // caps it at 2 GiB of the file; the rest is read as usual).
            conn.query_row("PRAGMA mmap_size = 1099511627776", [], |_| Ok(()))?;
            // CROSS JOIN keeps `messages` the outer loop, so the timestamp index gives the
            // order (no sort of the whole table) and a topic is looked up by its key.
            let mut stmt = conn.prepare(
                "SELECT m.data FROM messages AS m CROSS JOIN topics AS t ON m.topic_id = t.id \
                 WHERE t.name = ?1 ORDER BY m.timestamp, m.id",
            )?;
            let mut rows = stmt.query([topic])?;
            while let Some(row) = rows.next()? {
                let data = row.get_ref(0)?.as_blob().unwrap_or_default();
                let Some((width, height, start, n)) = event_array(data) else {
                    batch.unknown += 1;
                    continue;
                };
                batch.size.get_or_insert((width, height));
                let mut next = 0;
                while next < n {
                    let take = (n - next).min(chunk - batch.events.len());
                    push_events(data, start, next, take, &mut batch.events);
                    next += take;
                    if batch.events.len() == chunk {
                        // Full chunks from now on: allocated at their size, not grown.
                        let events =
                            std::mem::replace(&mut batch.events, Events::with_capacity(chunk));
                        let full = Batch { events, ..batch };
                        if tx.send(Ok(full)).is_err() {
                            return Ok(false);
                        }
                    }
                }
            }
            Ok(true)
        };
        match read() {
            Ok(true) => {}
            Ok(false) => return,
            Err(e) => {
                let _ = tx.send(Err(sql_error(path, e)));
                return;
            }
        }
    }
    let _ = tx.send(Ok(batch));
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
    /// A reader of `topic` in `paths` (read in that order), its thread decoding chunks of
    /// `chunk` events (`next_chunk` of that size hands them over without a copy). A file that
    /// cannot be opened as a bag (not SQLite, no `messages` or `topics` table) fails here.
    pub fn new(paths: &[PathBuf], topic: &str, chunk: usize) -> io::Result<Self> {
        for path in paths {
            let check = || -> rusqlite::Result<()> {
                let conn = open(path)?;
                conn.prepare("SELECT m.topic_id, m.timestamp, m.data FROM messages AS m LIMIT 0")?;
                conn.prepare("SELECT t.id, t.name, t.type FROM topics AS t LIMIT 0")?;
                Ok(())
            };
            check().map_err(|e| sql_error(path, e))?;
        }
        let (tx, rx) = sync_channel(1);
        let (paths, topic, chunk) = (paths.to_vec(), topic.to_string(), chunk.max(1));
        // Not joined: a reader dropped early (its channel closed) must not wait, the GIL held,
        // for the thread's query to reach its next row; the thread ends at its next send.
        std::thread::Builder::new()
            .name("evsplat-db3".into())
            .spawn(move || send_events(&paths, &topic, chunk, &tx))?;
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
