//! The SE(3) B-spline trajectory: numpy poses in, numpy poses and velocities out.

use glam::{DMat4, DVec4};
use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::value_err;
use evsplat_camera::distortion::{self, undistort_pixels};
use evsplat_camera::{Distortion, Se3, SplineSe3};

/// (angular, linear) body velocities, [N,3] each.
type Velocities<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// Cumulative cubic B-spline on SE(3). Times are float64 µs relative to an origin the caller
/// keeps (so absolute int64 timestamps never lose precision in a float).
#[pyclass(frozen, module = "evsplat._core")]
struct SplineTrajectory {
    inner: SplineSe3,
}

#[pymethods]
impl SplineTrajectory {
    /// Fit to `c2w` [N,4,4] at strictly increasing `times` [N]; `knot_interval` in µs or None.
    #[new]
    #[pyo3(signature = (times, c2w, knot_interval=None))]
    fn new(
        py: Python<'_>,
        times: PyReadonlyArray1<'_, f64>,
        c2w: PyReadonlyArray3<'_, f64>,
        knot_interval: Option<f64>,
    ) -> PyResult<Self> {
        let times = times.as_slice()?.to_vec();
        let m = c2w.as_array();
        if m.shape()[1..] != [4, 4] {
            return Err(PyValueError::new_err(format!(
                "poses must be [N,4,4], got {:?}",
                m.shape()
            )));
        }
        let poses: Vec<Se3> = m
            .outer_iter()
            .map(|p| {
                let col = |c: usize| DVec4::new(p[[0, c]], p[[1, c]], p[[2, c]], p[[3, c]]);
                Se3::from_mat4(&DMat4::from_cols(col(0), col(1), col(2), col(3)))
            })
            .collect();
        let inner = py
            .detach(|| SplineSe3::fit(&times, &poses, knot_interval))
            .map_err(value_err)?;
        Ok(SplineTrajectory { inner })
    }

    #[getter]
    fn t_min(&self) -> f64 {
        self.inner.t_min()
    }

    #[getter]
    fn t_max(&self) -> f64 {
        self.inner.t_max()
    }

    #[getter]
    fn knot_interval(&self) -> f64 {
        self.inner.knot_interval()
    }

    /// Camera-to-world poses [N,4,4] at `times` [N].
    fn pose<'py>(
        &self,
        py: Python<'py>,
        times: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let t = times.as_slice()?;
        let mats = py.detach(|| self.inner.poses(t)).map_err(value_err)?;
        let rows: Vec<Vec<Vec<f64>>> = mats
            .iter()
            .map(|m| {
                (0..4)
                    .map(|r| (0..4).map(|c| m.col(c)[r]).collect())
                    .collect()
            })
            .collect();
        if rows.is_empty() {
            return Ok(PyArray3::zeros(py, [0, 4, 4], false));
        }
        Ok(PyArray3::from_vec3(py, &rows)?)
    }

    /// Body-frame (angular rad/s [N,3], linear m/s [N,3]) velocities at `times` [N].
    fn velocity<'py>(
        &self,
        py: Python<'py>,
        times: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Velocities<'py>> {
        let t = times.as_slice()?;
        let vel = py.detach(|| self.inner.velocities(t)).map_err(value_err)?;
        let w: Vec<Vec<f64>> = vel.iter().map(|(w, _)| w.to_array().to_vec()).collect();
        let v: Vec<Vec<f64>> = vel.iter().map(|(_, v)| v.to_array().to_vec()).collect();
        if vel.is_empty() {
            return Ok((
                PyArray2::zeros(py, [0, 3], false),
                PyArray2::zeros(py, [0, 3], false),
            ));
        }
        Ok((PyArray2::from_vec2(py, &w)?, PyArray2::from_vec2(py, &v)?))
    }
}

fn lens(model: &str, coeffs: Vec<f64>) -> PyResult<Distortion> {
    Distortion::new(model, &coeffs).map_err(value_err)
}

/// Undistorts pixel `points` [N,2] (x, y) of a camera with intrinsics `k` = [fx, fy, cx, cy] and
/// lens `model` ("radtan" or "equidistant", OpenCV coefficient order) to ideal pinhole pixels
/// [N,2] with the same intrinsics; NaN where the lens model cannot be inverted.
#[pyfunction]
fn undistort_points<'py>(
    py: Python<'py>,
    model: &str,
    coeffs: Vec<f64>,
    k: [f64; 4],
    points: PyReadonlyArray2<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let d = lens(model, coeffs)?;
    let a = points.as_array();
    if a.shape()[1] != 2 {
        return Err(PyValueError::new_err(format!(
            "points must be [N,2], got {:?}",
            a.shape()
        )));
    }
    let pts: Vec<[f64; 2]> = a.outer_iter().map(|r| [r[0], r[1]]).collect();
    let n = pts.len();
    let out = py
        .detach(|| undistort_pixels(&d, k, &pts))
        .map_err(value_err)?;
    let flat: Vec<f64> = out.into_iter().flatten().collect();
    PyArray1::from_vec(py, flat).reshape([n, 2])
}

/// The rectification map [height, width, 2]: the undistorted pixel position of every pixel
/// centre (j + 0.5, i + 0.5) of a `width` x `height` sensor; NaN where the inverse fails.
#[pyfunction]
fn rectification_map<'py>(
    py: Python<'py>,
    model: &str,
    coeffs: Vec<f64>,
    k: [f64; 4],
    width: usize,
    height: usize,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let d = lens(model, coeffs)?;
    let map = py
        .detach(|| distortion::rectification_map(&d, k, width, height))
        .map_err(value_err)?;
    let flat: Vec<f64> = map.into_iter().flatten().collect();
    PyArray1::from_vec(py, flat).reshape([height, width, 2])
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<SplineTrajectory>()?;
    m.add_function(wrap_pyfunction!(undistort_points, m)?)?;
    m.add_function(wrap_pyfunction!(rectification_map, m)?)?;
    Ok(())
}
