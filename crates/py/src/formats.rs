//! The recording decoders (`evsplat_formats`) for Python: a file read chunk by chunk, each
//! chunk returned as numpy arrays, the GIL released while Rust reads and decodes.

use std::fs::File;
use std::io::{Seek, SeekFrom};

use pyo3::exceptions::PyOSError;
use pyo3::prelude::*;

use crate::errors::value_err;
use crate::events::{event_arrays, EventArrays};
use evsplat_formats::aedat4::{self, AedatReader, Compression};
use evsplat_formats::db3::{db3_topics, Db3Reader};
use evsplat_formats::mcap::{mcap_channels, McapFiles};
use evsplat_formats::rosbag::{bag_connections, BagReader};
use evsplat_formats::{ChunkReader, Encoding, EventSource, Ros2Compression};

/// `source`'s next chunk of at most `max_events` events as numpy arrays (empty at its end),
/// read and decoded with the GIL released.
fn next_chunk_of<'py, S: EventSource + Send>(
    py: Python<'py>,
    source: &mut S,
    max_events: usize,
) -> PyResult<EventArrays<'py>> {
    let ev = py
        .detach(|| source.next_chunk(max_events))
        .map_err(PyOSError::new_err)?;
    Ok(event_arrays(py, ev))
}

/// `source`'s (untimed events, unknown words or records, truncated bytes).
fn dropped_of<S: EventSource>(source: &S) -> (u64, u64, u64) {
    let s = source.stats();
    (s.untimed_events, s.unknown_words, s.truncated_bytes)
}

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
        next_chunk_of(py, &mut self.inner, max_events)
    }

    /// (CD events before the first time base, words of undefined types, bytes after the last
    /// complete word): final once `next_chunk` came back empty.
    fn dropped(&self) -> (u64, u64, u64) {
        dropped_of(&self.inner)
    }
}

/// The event arrays of a ROS 1 bag's `topic` (None: every event-array connection), read
/// through buffers that start at `block` bytes.
#[pyclass(module = "evsplat._core")]
struct BagEventDecoder {
    inner: BagReader<File>,
}

#[pymethods]
impl BagEventDecoder {
    #[new]
    #[pyo3(signature = (path, topic, block))]
    fn new(path: std::path::PathBuf, topic: Option<&str>, block: usize) -> PyResult<Self> {
        let file = File::open(&path).map_err(PyOSError::new_err)?;
        let inner = BagReader::new(file, topic, block).map_err(PyOSError::new_err)?;
        Ok(Self { inner })
    }

    /// (width, height) of the first event message (read up to it; its events are still to
    /// come), or None when the topic has no readable event message.
    fn sensor_size(&mut self, py: Python<'_>) -> PyResult<Option<(u32, u32)>> {
        py.detach(|| self.inner.sensor_size())
            .map_err(PyOSError::new_err)
    }

    /// The next chunk of at most `max_events` events; empty arrays at the end of the bag.
    fn next_chunk<'py>(
        &mut self,
        py: Python<'py>,
        max_events: usize,
    ) -> PyResult<EventArrays<'py>> {
        next_chunk_of(py, &mut self.inner, max_events)
    }

    /// (0, records not readable as what their header says, bytes of a last record the file
    /// ends in): final once `next_chunk` came back empty.
    fn dropped(&self) -> (u64, u64, u64) {
        dropped_of(&self.inner)
    }
}

/// The connections of a ROS 1 bag as (id, topic, type), from its index or, for an unindexed
/// bag, from a pass through its records.
#[pyfunction]
#[pyo3(name = "bag_connections")]
fn py_bag_connections(
    py: Python<'_>,
    path: std::path::PathBuf,
) -> PyResult<Vec<(u32, String, String)>> {
    let file = File::open(&path).map_err(PyOSError::new_err)?;
    let conns = py
        .detach(|| bag_connections(file, 1 << 16))
        .map_err(PyOSError::new_err)?;
    Ok(conns
        .into_iter()
        .map(|c| (c.id, c.topic, c.msgtype))
        .collect())
}

/// An AEDAT 4 file's header: (compression value, data table position or -1, the streams'
/// XML description, offset of the first packet).
#[pyfunction]
fn aedat4_header(path: std::path::PathBuf) -> PyResult<(i32, i64, String, u64)> {
    let mut file = std::io::BufReader::new(File::open(&path).map_err(PyOSError::new_err)?);
    let h = aedat4::read_header(&mut file).map_err(PyOSError::new_err)?;
    Ok((h.compression, h.data_table, h.description, h.data_start))
}

/// The events of stream `stream` of an AEDAT 4 file whose header `aedat4_header` read, through
/// a read buffer of `block` bytes.
#[pyclass(module = "evsplat._core")]
struct Aedat4EventDecoder {
    inner: AedatReader<File>,
}

#[pymethods]
impl Aedat4EventDecoder {
    #[new]
    fn new(
        path: std::path::PathBuf,
        compression: i32,
        stream: i32,
        data_start: u64,
        data_table: i64,
        block: usize,
    ) -> PyResult<Self> {
        let Some(compression) = Compression::from_header(compression) else {
            return Err(value_err(format!(
                "compression {compression} is unknown; AEDAT 4 defines 0 to 4"
            )));
        };
        let mut file = File::open(&path).map_err(PyOSError::new_err)?;
        file.seek(SeekFrom::Start(data_start))
            .map_err(PyOSError::new_err)?;
        let inner = AedatReader::new(file, compression, stream, data_start, data_table, block);
        Ok(Self { inner })
    }

    /// The next chunk of at most `max_events` events; empty arrays after the last packet.
    fn next_chunk<'py>(
        &mut self,
        py: Python<'py>,
        max_events: usize,
    ) -> PyResult<EventArrays<'py>> {
        next_chunk_of(py, &mut self.inner, max_events)
    }

    /// (0, packets of the stream that are not whole event packets, bytes of a packet the file
    /// ends in): final once `next_chunk` came back empty.
    fn dropped(&self) -> (u64, u64, u64) {
        dropped_of(&self.inner)
    }
}

/// metadata.yaml's `compression_mode` of a ROS 2 bag ("none", "message" or "file").
fn ros2_compression(mode: &str) -> PyResult<Ros2Compression> {
    Ros2Compression::from_mode(mode).ok_or_else(|| {
        value_err(format!(
            "compression {mode:?} is unknown; use none, message or file"
        ))
    })
}

/// The event arrays of a ROS 2 MCAP bag's `topic` (None: every event-array channel), from
/// its files (`paths`, read one after another: a split bag; `compression`: metadata.yaml's
/// `compression_mode` of zstd, "none", "message" or "file"), each through a buffer of `block`
/// bytes.
#[pyclass(module = "evsplat._core")]
struct McapEventDecoder {
    inner: McapFiles,
}

#[pymethods]
impl McapEventDecoder {
    #[new]
    #[pyo3(signature = (paths, topic, block, compression = "none"))]
    fn new(
        paths: Vec<std::path::PathBuf>,
        topic: Option<&str>,
        block: usize,
        compression: &str,
    ) -> PyResult<Self> {
        let compression = ros2_compression(compression)?;
        let inner =
            McapFiles::new(&paths, topic, compression, block).map_err(PyOSError::new_err)?;
        Ok(Self { inner })
    }

    /// (width, height) of the first event message (read up to it), or None.
    fn sensor_size(&mut self, py: Python<'_>) -> PyResult<Option<(u32, u32)>> {
        py.detach(|| self.inner.sensor_size())
            .map_err(PyOSError::new_err)
    }

    /// The next chunk of at most `max_events` events; empty arrays at the end of the data.
    fn next_chunk<'py>(
        &mut self,
        py: Python<'py>,
        max_events: usize,
    ) -> PyResult<EventArrays<'py>> {
        next_chunk_of(py, &mut self.inner, max_events)
    }

    /// (0, records not readable as what their op says, bytes of a last record a file ends
    /// in): final once `next_chunk` came back empty.
    fn dropped(&self) -> (u64, u64, u64) {
        dropped_of(&self.inner)
    }
}

/// The channels of an MCAP file as (id, topic, type), from its summary or a pass through it.
#[pyfunction]
#[pyo3(name = "mcap_channels")]
fn py_mcap_channels(
    py: Python<'_>,
    path: std::path::PathBuf,
) -> PyResult<Vec<(u16, String, String)>> {
    let file = File::open(&path).map_err(PyOSError::new_err)?;
    let channels = py
        .detach(|| mcap_channels(file, 1 << 16))
        .map_err(PyOSError::new_err)?;
    Ok(channels
        .into_iter()
        .map(|c| (c.id, c.topic, c.msgtype))
        .collect())
}

/// The event arrays of a ROS 2 SQLite bag's `topic`, in timestamp order, from its .db3
/// files (`paths`, read in that order: a split bag; `compression`: metadata.yaml's
/// `compression_mode` of zstd, "none", "message" or "file"), decoded by a thread in chunks of
/// `chunk` events.
#[pyclass(module = "evsplat._core")]
struct Db3EventDecoder {
    inner: Db3Reader,
}

#[pymethods]
impl Db3EventDecoder {
    #[new]
    #[pyo3(signature = (paths, topic, chunk, compression = "none"))]
    fn new(
        paths: Vec<std::path::PathBuf>,
        topic: &str,
        chunk: usize,
        compression: &str,
    ) -> PyResult<Self> {
        let compression = ros2_compression(compression)?;
        let inner =
            Db3Reader::new(&paths, topic, compression, chunk).map_err(PyOSError::new_err)?;
        Ok(Self { inner })
    }

    /// (width, height) of the first event message (read up to it), or None.
    fn sensor_size(&mut self, py: Python<'_>) -> PyResult<Option<(u32, u32)>> {
        py.detach(|| self.inner.sensor_size())
            .map_err(PyOSError::new_err)
    }

    /// The next chunk of at most `max_events` events; empty arrays at the end of the topic.
    fn next_chunk<'py>(
        &mut self,
        py: Python<'py>,
        max_events: usize,
    ) -> PyResult<EventArrays<'py>> {
        next_chunk_of(py, &mut self.inner, max_events)
    }

    /// (0, messages not of the EventArray layout, 0): final once `next_chunk` came back empty.
    fn dropped(&self) -> (u64, u64, u64) {
        dropped_of(&self.inner)
    }
}

/// The topics of a .db3 file as (id, topic, type).
#[pyfunction]
#[pyo3(name = "db3_topics")]
fn py_db3_topics(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Vec<(i64, String, String)>> {
    let topics = py
        .detach(|| db3_topics(&path))
        .map_err(PyOSError::new_err)?;
    Ok(topics
        .into_iter()
        .map(|t| (t.id, t.name, t.msgtype))
        .collect())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Db3EventDecoder>()?;
    m.add_function(wrap_pyfunction!(py_db3_topics, m)?)?;
    m.add_class::<McapEventDecoder>()?;
    m.add_function(wrap_pyfunction!(py_mcap_channels, m)?)?;
    m.add_class::<Aedat4EventDecoder>()?;
    m.add_function(wrap_pyfunction!(aedat4_header, m)?)?;
    m.add_class::<EventFileDecoder>()?;
    m.add_class::<BagEventDecoder>()?;
    m.add_function(wrap_pyfunction!(py_bag_connections, m)?)?;
    Ok(())
}
