//! The event core (`evsplat_events`) for numpy: arrays in as borrowed slices, results out as
//! new arrays, the GIL released while Rust works. Errors become ValueError; the Python layer
//! adds the file or argument name.

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::value_err;

use evsplat_events as ev;
use evsplat_events::{Contrast, EventError, EventSlice, Sensor, Threshold};

/// Owned event columns as numpy arrays: x, y (uint16), t (int64 µs), p (int8).
pub(crate) type EventArrays<'py> = (
    Bound<'py, PyArray1<u16>>,
    Bound<'py, PyArray1<u16>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i8>>,
);

/// Hands `events`' columns to numpy without copying them.
pub(crate) fn event_arrays(py: Python<'_>, events: ev::Events) -> EventArrays<'_> {
    (
        PyArray1::from_vec(py, events.x),
        PyArray1::from_vec(py, events.y),
        PyArray1::from_vec(py, events.t),
        PyArray1::from_vec(py, events.p),
    )
}

/// A contrast threshold from Python: a float, or a contiguous float32 array with one value per
/// pixel (flattened row-major).
#[derive(FromPyObject)]
enum ThresholdArg<'py> {
    Scalar(f32),
    Map(PyReadonlyArray1<'py, f32>),
}

impl ThresholdArg<'_> {
    fn get(&self) -> PyResult<Threshold<'_>> {
        Ok(match self {
            ThresholdArg::Scalar(v) => Threshold::Scalar(*v),
            ThresholdArg::Map(a) => Threshold::Map(a.as_slice()?),
        })
    }
}

/// An `EventStream` (python/evsplat/data/events.py), read by attribute: its arrays borrowed
/// without copying, and its sensor size.
#[derive(FromPyObject)]
struct Stream<'py> {
    x: PyReadonlyArray1<'py, u16>,
    y: PyReadonlyArray1<'py, u16>,
    t: PyReadonlyArray1<'py, i64>,
    p: PyReadonlyArray1<'py, i8>,
    width: u64,
    height: u64,
}

/// A stream's arrays as slices, with its checked sensor.
struct Arrays<'a> {
    x: &'a [u16],
    y: &'a [u16],
    t: &'a [i64],
    p: &'a [i8],
    sensor: Sensor,
}

impl Stream<'_> {
    fn arrays(&self) -> PyResult<Arrays<'_>> {
        Ok(Arrays {
            sensor: sensor(self.width, self.height)?,
            x: self.x.as_slice()?,
            y: self.y.as_slice()?,
            t: self.t.as_slice()?,
            p: self.p.as_slice()?,
        })
    }
}

impl<'a> Arrays<'a> {
    /// The validated events `[i0, i1)`.
    fn window(&self, i0: i64, i1: i64) -> Result<EventSlice<'a>, EventError> {
        let (a, b) = ev::check_range(i0, i1, self.x.len())?;
        EventSlice::new(&self.x[a..b], &self.y[a..b], &self.p[a..b], self.sensor)
    }
}

fn sensor(width: u64, height: u64) -> PyResult<Sensor> {
    Sensor::new(width, height).map_err(value_err)
}

/// Validates a stream in canonical dtypes. Returns the polarity mapped to ±1 when the input
/// used 0/1, else None (the input is already canonical).
#[pyfunction]
fn validate_events<'py>(
    py: Python<'py>,
    events: Stream<'py>,
) -> PyResult<Option<Bound<'py, PyArray1<i8>>>> {
    let a = events.arrays()?;
    let mapped = py.detach(|| {
        ev::validate(a.x, a.y, a.t, a.p, a.sensor).map(|c| match c {
            std::borrow::Cow::Owned(v) => Some(v),
            std::borrow::Cow::Borrowed(_) => None,
        })
    });
    Ok(mapped
        .map_err(value_err)?
        .map(|v| PyArray1::from_vec(py, v)))
}

/// Polarities given as integers of any width, mapped to ±1 (i8).
#[pyfunction]
fn polarity_from_int64<'py>(
    py: Python<'py>,
    p: PyReadonlyArray1<'py, i64>,
) -> PyResult<Bound<'py, PyArray1<i8>>> {
    let p = p.as_slice()?;
    let out = py.detach(|| ev::polarity_from_i64(p)).map_err(value_err)?;
    Ok(PyArray1::from_vec(py, out))
}

/// Whole-numbered floats to int64; NaN, infinities, fractions and overflow are errors.
#[pyfunction]
fn float_to_int64<'py>(
    py: Python<'py>,
    values: PyReadonlyArray1<'py, f64>,
    name: &str,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let name = static_name(name);
    let v = values.as_slice()?;
    let out = py.detach(|| ev::float_to_i64(v, name)).map_err(value_err)?;
    Ok(PyArray1::from_vec(py, out))
}

/// int64 coordinates to uint16, checking `0 <= v < limit` (limit = width for x, height for y).
#[pyfunction]
fn coords_to_uint16<'py>(
    py: Python<'py>,
    values: PyReadonlyArray1<'py, i64>,
    axis: &str,
    limit: u32,
) -> PyResult<Bound<'py, PyArray1<u16>>> {
    let (axis, dim) = if axis == "x" {
        ("x", "width")
    } else {
        ("y", "height")
    };
    let v = values.as_slice()?;
    let out = py
        .detach(|| ev::coords_to_u16(v, axis, dim, limit))
        .map_err(value_err)?;
    Ok(PyArray1::from_vec(py, out))
}

/// Error messages name the array; these are the names the Python layer uses.
fn static_name(name: &str) -> &'static str {
    match name {
        "x" => "x",
        "y" => "y",
        "t" => "t",
        "p" => "p",
        "bounds" => "bounds",
        _ => "value",
    }
}

/// Index range of the events with `t0 <= t < t1`.
#[pyfunction]
fn window_by_time(
    py: Python<'_>,
    t: PyReadonlyArray1<'_, i64>,
    t0: i64,
    t1: i64,
) -> PyResult<(usize, usize)> {
    let t = t.as_slice()?;
    Ok(py.detach(|| ev::window_by_time(t, t0, t1)))
}

/// Index range of `count` events from `start`, clipped to a stream of `len` events.
#[pyfunction]
fn window_by_count(len: usize, start: i64, count: i64) -> PyResult<(usize, usize)> {
    ev::window_by_count(len, start, count).map_err(value_err)
}

/// `m + 1` boundaries splitting `[i0, i1)` of a stream of `len` events into equal counts.
#[pyfunction]
fn split_equal_count<'py>(
    py: Python<'py>,
    len: usize,
    i0: i64,
    i1: i64,
    m: usize,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let (a, b) = ev::check_range(i0, i1, len).map_err(value_err)?;
    Ok(PyArray1::from_vec(
        py,
        ev::split_equal_count(a, b, m).map_err(value_err)?,
    ))
}

/// ESI, event count and event mask of `[i0, i1)` from one counting pass; `want` selects which
/// ("esi", "count", "mask"), so unused outputs cost nothing.
#[pyfunction]
fn accumulate<'py>(
    py: Python<'py>,
    events: Stream<'py>,
    i0: i64,
    i1: i64,
    c_pos: ThresholdArg<'py>,
    c_neg: ThresholdArg<'py>,
    want: Vec<String>,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let a = events.arrays()?;
    let s = a.sensor;
    let c = Contrast {
        pos: c_pos.get()?,
        neg: c_neg.get()?,
    };
    let counts = py
        .detach(|| {
            c.check(s)?;
            ev::polarity_counts(&a.window(i0, i1)?)
        })
        .map_err(value_err)?;
    let shape = [s.height as usize, s.width as usize];
    want.iter()
        .map(|w| {
            Ok(match w.as_str() {
                "esi" => PyArray1::from_vec(py, py.detach(|| counts.esi(&c)))
                    .reshape(shape)?
                    .into_any(),
                "count" => PyArray1::from_vec(py, py.detach(|| counts.total()))
                    .reshape(shape)?
                    .into_any(),
                "mask" => PyArray1::from_vec(py, py.detach(|| counts.mask()))
                    .reshape(shape)?
                    .into_any(),
                other => {
                    return Err(PyValueError::new_err(format!(
                        "unknown output '{other}'; use esi, count or mask"
                    )))
                }
            })
        })
        .collect()
}

/// Event mask of `[i0, i1)` alone (no counts: a smaller image to scatter into).
#[pyfunction]
fn event_mask<'py>(
    py: Python<'py>,
    events: Stream<'py>,
    i0: i64,
    i1: i64,
) -> PyResult<Bound<'py, PyAny>> {
    let a = events.arrays()?;
    let s = a.sensor;
    let mask = py
        .detach(|| ev::event_mask(&a.window(i0, i1)?))
        .map_err(value_err)?;
    Ok(PyArray1::from_vec(py, mask)
        .reshape([s.height as usize, s.width as usize])?
        .into_any())
}

/// ESI of `[i0, i1)` split by colour-filter channel: (C, H, W), C = 3 for Bayer, 1 for mono.
#[pyfunction]
fn esi_by_channel<'py>(
    py: Python<'py>,
    events: Stream<'py>,
    i0: i64,
    i1: i64,
    c_pos: ThresholdArg<'py>,
    c_neg: ThresholdArg<'py>,
    pattern: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let a = events.arrays()?;
    let s = a.sensor;
    let bayer = ev::Bayer::parse(pattern).map_err(value_err)?;
    let c = Contrast {
        pos: c_pos.get()?,
        neg: c_neg.get()?,
    };
    let out = py
        .detach(|| {
            c.check(s)?;
            let esi = ev::polarity_counts(&a.window(i0, i1)?)?.esi(&c);
            Ok::<_, EventError>(bayer.split(&esi, s))
        })
        .map_err(value_err)?;
    Ok(PyArray1::from_vec(py, out)
        .reshape([bayer.channels(), s.height as usize, s.width as usize])?
        .into_any())
}

/// Channel index (0=R, 1=G, 2=B) of every pixel for a Bayer pattern; zeros for mono.
#[pyfunction]
fn bayer_channel_map<'py>(
    py: Python<'py>,
    pattern: &str,
    width: u64,
    height: u64,
) -> PyResult<Bound<'py, PyAny>> {
    let s = sensor(width, height)?;
    let map = ev::Bayer::parse(pattern).map_err(value_err)?.channel_map(s);
    Ok(PyArray1::from_vec(py, map)
        .reshape([s.height as usize, s.width as usize])?
        .into_any())
}

/// Patches (n, m, side, side) of the sub-window ESIs around `centres` and their validity.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn patches<'py>(
    py: Python<'py>,
    events: Stream<'py>,
    bounds: PyReadonlyArray1<'py, i64>,
    centres: PyReadonlyArray1<'py, f32>,
    per_window: bool,
    side: usize,
    c_pos: ThresholdArg<'py>,
    c_neg: ThresholdArg<'py>,
    mode: &str,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let a = events.arrays()?;
    let mode = ev::Sampling::parse(mode).map_err(value_err)?;
    let (bounds, centres) = (bounds.as_slice()?, centres.as_slice()?);
    let c = Contrast {
        pos: c_pos.get()?,
        neg: c_neg.get()?,
    };
    let out = py
        .detach(|| {
            let all = EventSlice::new(a.x, a.y, a.p, a.sensor)?;
            ev::extract_patches(&all, bounds, centres, per_window, side, &c, mode)
        })
        .map_err(value_err)?;
    let m = bounds.len() - 1;
    let n = if m == 0 {
        0
    } else {
        out.values.len() / (m * side * side)
    };
    let shape = [n, m, side, side];
    Ok((
        PyArray1::from_vec(py, out.values)
            .reshape(shape)?
            .into_any(),
        PyArray1::from_vec(py, out.valid).reshape(shape)?.into_any(),
    ))
}

/// Voxel grid (bins, H, W) of `[i0, i1)`, polarity bilinear in normalised time.
#[pyfunction]
fn voxel_grid<'py>(
    py: Python<'py>,
    events: Stream<'py>,
    i0: i64,
    i1: i64,
    bins: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let a = events.arrays()?;
    let s = a.sensor;
    let out = py
        .detach(|| {
            let e = a.window(i0, i1)?;
            let (lo, hi) = ev::check_range(i0, i1, a.t.len())?;
            ev::voxel_grid(&e, &a.t[lo..hi], bins)
        })
        .map_err(value_err)?;
    Ok(PyArray1::from_vec(py, out)
        .reshape([bins, s.height as usize, s.width as usize])?
        .into_any())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(validate_events, m)?)?;
    m.add_function(wrap_pyfunction!(polarity_from_int64, m)?)?;
    m.add_function(wrap_pyfunction!(float_to_int64, m)?)?;
    m.add_function(wrap_pyfunction!(coords_to_uint16, m)?)?;
    m.add_function(wrap_pyfunction!(window_by_time, m)?)?;
    m.add_function(wrap_pyfunction!(window_by_count, m)?)?;
    m.add_function(wrap_pyfunction!(split_equal_count, m)?)?;
    m.add_function(wrap_pyfunction!(accumulate, m)?)?;
    m.add_function(wrap_pyfunction!(event_mask, m)?)?;
    m.add_function(wrap_pyfunction!(esi_by_channel, m)?)?;
    m.add_function(wrap_pyfunction!(bayer_channel_map, m)?)?;
    m.add_function(wrap_pyfunction!(patches, m)?)?;
    m.add_function(wrap_pyfunction!(voxel_grid, m)?)?;
    Ok(())
}
