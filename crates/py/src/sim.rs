//! The ESIM-style event simulator: push numpy log-intensity frames, get event arrays back.

use numpy::ndarray::Array;
use numpy::{
    IntoPyArray, PyArray2, PyArray3, PyReadonlyArray2, PyReadonlyArray3, PyReadonlyArrayDyn,
};
use pyo3::prelude::*;

use crate::errors::value_err;
use crate::events::{event_arrays, EventArrays};
use evsplat_sim::render::{self, Pose, Primitive};
use evsplat_sim::{Bayer, SimConfig};

#[pyclass(module = "evsplat._core")]
struct EventSimulator {
    inner: evsplat_sim::EventSimulator,
}

#[pymethods]
impl EventSimulator {
    #[new]
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (width, height, c_pos, c_neg, sigma_c, refractory_us, noise_rate_hz, hot_pixels, hot_rate_hz, bayer, seed))]
    fn new(
        width: usize,
        height: usize,
        c_pos: f64,
        c_neg: f64,
        sigma_c: f64,
        refractory_us: i64,
        noise_rate_hz: f64,
        hot_pixels: usize,
        hot_rate_hz: f64,
        bayer: &str,
        seed: u64,
    ) -> PyResult<Self> {
        let bayer = Bayer::parse(bayer).map_err(value_err)?;
        let cfg = SimConfig {
            c_pos,
            c_neg,
            sigma_c,
            refractory_us,
            noise_rate_hz,
            hot_pixels,
            hot_rate_hz,
            bayer,
            seed,
        };
        let inner = evsplat_sim::EventSimulator::new(width, height, cfg).map_err(value_err)?;
        Ok(EventSimulator { inner })
    }

    /// Add the log frame at `t_us` ([H,W] mono or [H,W,3] RGB float32, C-contiguous) and return
    /// the events since the previous frame as (x, y, t, p).
    fn push<'py>(
        &mut self,
        py: Python<'py>,
        t_us: i64,
        frame: PyReadonlyArrayDyn<'py, f32>,
    ) -> PyResult<EventArrays<'py>> {
        let data = frame.as_slice()?;
        let inner = &mut self.inner;
        let ev = py.detach(|| inner.push(t_us, data)).map_err(value_err)?;
        Ok(event_arrays(py, ev))
    }
}

fn pose_of(m: numpy::ndarray::ArrayView2<'_, f64>) -> Pose {
    Pose {
        r: [
            m[[0, 0]],
            m[[0, 1]],
            m[[0, 2]],
            m[[1, 0]],
            m[[1, 1]],
            m[[1, 2]],
            m[[2, 0]],
            m[[2, 1]],
            m[[2, 2]],
        ],
        t: [m[[0, 3]], m[[1, 3]], m[[2, 3]]],
    }
}

type FrameArrays<'py> = (
    Bound<'py, PyArray3<f32>>,
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray2<bool>>,
);

/// (shape, size, texture, texture parameters, moving) as the Python scene library gives them.
type PrimitiveSpec = (String, Vec<f64>, String, Vec<f64>, bool);

/// Analytic ray caster for the synthetic scenes (independent of the splatting rasterizer).
#[pyclass(frozen, module = "evsplat._core")]
struct SceneRenderer {
    prims: Vec<Primitive>,
    width: usize,
    height: usize,
    k: [f64; 4],
    samples: usize,
}

#[pymethods]
impl SceneRenderer {
    /// `primitives`: (shape, size, texture, texture_params, moving) per primitive;
    /// `k`: (fx, fy, cx, cy); `samples`: rays per pixel side (odd; each pixel's colour is their
    /// mean).
    #[new]
    fn new(
        primitives: Vec<PrimitiveSpec>,
        width: usize,
        height: usize,
        k: [f64; 4],
        samples: usize,
    ) -> PyResult<Self> {
        let prims = primitives
            .iter()
            .map(|(shape, size, tex, params, moving)| {
                Primitive::new(shape, size, tex, params, *moving)
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(value_err)?;
        Ok(SceneRenderer {
            prims,
            width,
            height,
            k,
            samples,
        })
    }

    /// Render with camera-to-world `c2w` [4,4] and object-to-world `poses` [n,4,4]:
    /// (rgb [H,W,3], depth [H,W], moving mask [H,W]).
    fn render<'py>(
        &self,
        py: Python<'py>,
        c2w: PyReadonlyArray2<'py, f64>,
        poses: PyReadonlyArray3<'py, f64>,
    ) -> PyResult<FrameArrays<'py>> {
        let cam = pose_of(c2w.as_array());
        let poses: Vec<Pose> = poses.as_array().outer_iter().map(pose_of).collect();
        let (w, h) = (self.width, self.height);
        let f = py
            .detach(|| render::render(&self.prims, &poses, cam, self.k, (w, h), self.samples))
            .map_err(value_err)?;
        Ok((
            Array::from_shape_vec((h, w, 3), f.rgb)
                .map_err(value_err)?
                .into_pyarray(py),
            Array::from_shape_vec((h, w), f.depth)
                .map_err(value_err)?
                .into_pyarray(py),
            Array::from_shape_vec((h, w), f.mask)
                .map_err(value_err)?
                .into_pyarray(py),
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<EventSimulator>()?;
    m.add_class::<SceneRenderer>()?;
    m.add("MAX_PIXEL_SAMPLES", render::MAX_SAMPLES)?;
    Ok(())
}
