//! PNG and EXR image files (atomic writes) as numpy float32 arrays.

use std::path::PathBuf;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods, ToPyArray};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::value_err;
use evsplat_io::FloatImage;

fn to_numpy<'py>(py: Python<'py>, img: FloatImage) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let shape: Vec<usize> = if img.channels == 1 {
        vec![img.height, img.width]
    } else {
        vec![img.height, img.width, img.channels]
    };
    let arr = numpy::ndarray::ArrayD::from_shape_vec(shape, img.data).map_err(value_err)?;
    Ok(arr.to_pyarray(py))
}

fn dims(shape: &[usize]) -> PyResult<(usize, usize, usize)> {
    match *shape {
        [h, w] => Ok((h, w, 1)),
        [h, w, c] => Ok((h, w, c)),
        _ => Err(PyValueError::new_err(format!(
            "image must be [H,W] or [H,W,C], got shape {shape:?}"
        ))),
    }
}

/// Write [H,W] or [H,W,3] float32 values in [0,1] as an 8- or 16-bit PNG.
#[pyfunction]
fn write_png(
    py: Python<'_>,
    path: PathBuf,
    img: PyReadonlyArrayDyn<'_, f32>,
    bits16: bool,
) -> PyResult<()> {
    let (h, w, c) = dims(img.shape())?;
    let data = img.as_slice()?;
    py.detach(|| evsplat_io::write_png(&path, data, w, h, c, bits16))
        .map_err(value_err)
}

/// Read a PNG as float32 in [0,1]: [H,W] for grey, [H,W,3] for colour.
#[pyfunction]
fn read_png<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let img = py
        .detach(|| evsplat_io::read_png(&path))
        .map_err(value_err)?;
    to_numpy(py, img)
}

/// Write an [H,W] float32 depth map as a one-channel EXR.
#[pyfunction]
fn write_exr(py: Python<'_>, path: PathBuf, depth: PyReadonlyArrayDyn<'_, f32>) -> PyResult<()> {
    let (h, w, c) = dims(depth.shape())?;
    if c != 1 {
        return Err(PyValueError::new_err(format!(
            "depth must be [H,W], got shape {:?}",
            depth.shape()
        )));
    }
    let data = depth.as_slice()?;
    py.detach(|| evsplat_io::write_exr(&path, data, w, h))
        .map_err(value_err)
}

/// Read the depth channel of an EXR as [H,W] float32.
#[pyfunction]
fn read_exr<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let img = py
        .detach(|| evsplat_io::read_exr(&path))
        .map_err(value_err)?;
    to_numpy(py, img)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(write_png, m)?)?;
    m.add_function(wrap_pyfunction!(read_png, m)?)?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    Ok(())
}
