//! A recording's event words read through a bounded buffer and decoded chunk by chunk.

use std::io::{self, Read};

use crate::{dat, evt2, evt3, Decode, EventSource, Events, Stats};

/// The binary encodings this crate decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    Evt2,
    Evt3,
    Dat,
}

impl Encoding {
    /// Bytes per word or record: a file's tail shorter than this is a truncated record.
    pub fn word(self) -> usize {
        match self {
            Encoding::Evt2 => evt2::Decoder::WORD,
            Encoding::Evt3 => evt3::Decoder::WORD,
            Encoding::Dat => dat::Decoder::WORD,
        }
    }

    /// Most events one word or record can produce.
    pub fn max_per_word(self) -> usize {
        match self {
            Encoding::Evt2 => evt2::Decoder::MAX_PER_WORD,
            Encoding::Evt3 => evt3::Decoder::MAX_PER_WORD,
            Encoding::Dat => dat::Decoder::MAX_PER_WORD,
        }
    }
}

#[derive(Debug, Clone)]
enum State {
    Evt2(evt2::Decoder),
    Evt3(evt3::Decoder),
    Dat(dat::Decoder),
}

/// Reads `src` through a buffer of `block` bytes and returns its events in chunks of at most
/// `max_events`; the decoder's state crosses both buffer and chunk boundaries. Memory is the
/// buffer plus one chunk, whatever the recording's length.
#[derive(Debug)]
pub struct ChunkReader<R> {
    src: R,
    buf: Vec<u8>,
    start: usize,
    end: usize,
    eof: bool,
    encoding: Encoding,
    state: State,
    stats: Stats,
}

impl<R: Read> ChunkReader<R> {
    /// A reader of `src` (positioned at the first word) with a buffer of `block` bytes,
    /// raised to one word.
    pub fn new(src: R, encoding: Encoding, block: usize) -> Self {
        let state = match encoding {
            Encoding::Evt2 => State::Evt2(Default::default()),
            Encoding::Evt3 => State::Evt3(Default::default()),
            Encoding::Dat => State::Dat(Default::default()),
        };
        Self {
            src,
            buf: vec![0; block.max(encoding.word())],
            start: 0,
            end: 0,
            eof: false,
            encoding,
            state,
            stats: Stats::default(),
        }
    }

    /// Moves the partial word left in the buffer to its front and reads after it.
    fn refill(&mut self) -> io::Result<()> {
        self.buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        while self.end < self.buf.len() {
            match self.src.read(&mut self.buf[self.end..]) {
                Ok(0) => {
                    self.eof = true;
                    break;
                }
                Ok(n) => self.end += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}

impl<R: Read> EventSource for ChunkReader<R> {
    fn stats(&self) -> Stats {
        self.stats
    }

    /// A trailing partial word is counted in `stats().truncated_bytes`.
    fn next_chunk(&mut self, max_events: usize) -> io::Result<Events> {
        let max_events = max_events.max(1);
        if self.end - self.start < self.encoding.word() && !self.eof {
            self.refill()?;
        }
        // A full chunk's room at once (growing it would move it and fault in fresh pages),
        // unless the rest of the input is in the buffer: then its words, so that a small input
        // allocates little (EVT 3.0 vectors may still grow it).
        let words = (self.end - self.start) / self.encoding.word();
        let mut out = Events::with_capacity(if self.eof {
            words.min(max_events)
        } else {
            max_events
        });
        loop {
            let bytes = &self.buf[self.start..self.end];
            self.start += match &mut self.state {
                State::Evt2(d) => d.decode(bytes, &mut out, max_events, &mut self.stats),
                State::Evt3(d) => d.decode(bytes, &mut out, max_events, &mut self.stats),
                State::Dat(d) => d.decode(bytes, &mut out, max_events, &mut self.stats),
            };
            if out.len() == max_events {
                return Ok(out);
            }
            if self.eof {
                self.stats.truncated_bytes += (self.end - self.start) as u64;
                self.start = self.end;
                return Ok(out);
            }
            self.refill()?;
        }
    }
}
