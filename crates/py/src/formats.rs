//! The recording decoders (`evsplat_formats`) for Python: a file read chunk by chunk, each
//! chunk returned as numpy arrays, the GIL released while Rust reads and decodes.

use std::fs::File;
use std::io::{Seek, SeekFrom};

use pyo3::exceptions::PyOSError;
use pyo3::prelude::*;

use crate::errors::value_err;
use crate::events::{event_arrays, EventArrays};
use evsplat_formats::{ChunkReader, Encoding};

/// The event words of a recording from byte `offset` on ("evt2", "evt3" or "dat"), read
/// through a buffer of `block` bytes.
#[pyclass(module = "evsplat._core")]
struct EventFileDecoder {
    inner: ChunkReader<File>,
}

#[pymethods]
impl EventFileDecoder {
    #[new]
    fn new(path: std::path::PathBuf, encoding: &str, offset: u64, block: usize) -> PyResult<Self> {
        let encoding = match encoding {
            "evt2" => Encoding::Evt2,
            "evt3" => Encoding::Evt3,
            "dat" => Encoding::Dat,
            other => {
                return Err(value_err(format!(
                    "encoding {other:?} is unknown; use evt2, evt3 or dat"
                )))
            }
        };
        let mut file = File::open(&path).map_err(PyOSError::new_err)?;
        file.seek(SeekFrom::Start(offset))
            .map_err(PyOSError::new_err)?;
        Ok(Self {
            inner: ChunkReader::new(file, encoding, block),
        })
    }

    /// The next chunk of at most `max_events` events; empty arrays at the end of the file.
    fn next_chunk<'py>(
        &mut self,
        py: Python<'py>,
        max_events: usize,
    ) -> PyResult<EventArrays<'py>> {
        let ev = py
            .detach(|| self.inner.next_chunk(max_events))
            .map_err(PyOSError::new_err)?;
        Ok(event_arrays(py, ev))
    }

    /// (CD events before the first time base, words of undefined types, bytes after the last
    /// complete word): final once `next_chunk` came back empty.
    fn dropped(&self) -> (u64, u64, u64) {
        let s = self.inner.stats();
        (s.untimed_events, s.unknown_words, s.truncated_bytes)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<EventFileDecoder>()?;
    Ok(())
}
