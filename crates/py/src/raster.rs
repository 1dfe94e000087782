//! The splatting rasterizer: flat float32 numpy arrays in, numpy arrays out; logic lives in
//! evsplat_raster::splat.

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use evsplat_raster::host;
use evsplat_raster::{
    rasterize_backward as gpu_backward, rasterize_finish as gpu_finish,
    rasterize_forward as gpu_forward, rasterize_submit as gpu_submit, AtomicMode, Camera,
    ForwardOutput, Gaussians, GpuError, OutputGrads, PassTimes, PendingForward, Render,
};

use crate::errors::value_err;
use crate::gpu::context;

fn raster_err(e: GpuError) -> PyErr {
    match e {
        GpuError::Invalid(m) | GpuError::OverLimit(m) => value_err(m),
        other => crate::gpu::gpu_err(other),
    }
}

type F32<'py> = PyReadonlyArray1<'py, f32>;

/// One forward render, as `rasterize_backward` needs it; returned by `rasterize_forward`.
#[pyclass(frozen, module = "evsplat._core")]
struct RenderState(Render);

/// A forward render on its way (`rasterize_submit`), read back once by `rasterize_finish`.
#[pyclass(frozen, module = "evsplat._core")]
struct PendingRender(std::sync::Mutex<Option<PendingForward>>);

fn camera(viewmat: &[f32], k: &[f32], size: (u32, u32), range: (f32, f32)) -> PyResult<Camera> {
    let viewmat: [f32; 16] = viewmat
        .try_into()
        .map_err(|_| PyValueError::new_err("viewmat must have 16 values"))?;
    let k: [f32; 9] = k
        .try_into()
        .map_err(|_| PyValueError::new_err("K must have 9 values"))?;
    Ok(Camera {
        viewmat,
        k,
        width: size.0,
        height: size.1,
        near: range.0,
        far: range.1,
    })
}

fn times_dict<'py>(py: Python<'py>, times: &PassTimes) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (name, t) in times {
        d.set_item(*name, *t)?;
    }
    Ok(d)
}

/// The Gaussians of a call, borrowed from its numpy arguments (as `rasterize_forward` takes
/// them; the backward takes them again to redo the render when it must).
fn gaussians<'a>(
    [means, quats, scales, opacities, features, background]: [&'a F32<'_>; 6],
    d: usize,
) -> PyResult<Gaussians<'a>> {
    Ok(Gaussians {
        means: means.as_slice()?,
        quats: quats.as_slice()?,
        scales: scales.as_slice()?,
        opacities: opacities.as_slice()?,
        features: features.as_slice()?,
        d,
        background: background.as_slice()?,
    })
}

/// The Rust side of a call, with the GIL released and timed as the host phase "rust call"
/// (its own phases included; what is left of the call is PyO3's argument conversion). Phases
/// of earlier calls are dropped first, so `add_times` reports this call's only.
fn timed_call<T: Send>(py: Python<'_>, f: impl Send + FnOnce() -> PyResult<T>) -> PyResult<T> {
    host::take();
    host::time("rust call", || py.detach(f))
}

/// Adds the per-pass times ("times", filled when profiling) and the call's host phases
/// ("host") to its result.
fn add_times(r: &Bound<'_, PyDict>, times: &PassTimes) -> PyResult<()> {
    let py = r.py();
    r.set_item("times", times_dict(py, times)?)?;
    r.set_item("host", times_dict(py, &host::take())?)
}

/// Forward render. Arrays are flat float32; returns image (H*W*D), depth, alpha, radii, means2d,
/// depths, intersections, state (for the backward), (when `profile`) per-pass host times in
/// seconds, the call's host phases in seconds ("host") and (when `count_work`) the compositing
/// pass's step counts, else None.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (means, quats, scales, opacities, features, d, background, viewmat, k, width, height, near, far, profile=false, count_work=false))]
fn rasterize_forward<'py>(
    py: Python<'py>,
    means: F32<'py>,
    quats: F32<'py>,
    scales: F32<'py>,
    opacities: F32<'py>,
    features: F32<'py>,
    d: usize,
    background: F32<'py>,
    viewmat: F32<'py>,
    k: F32<'py>,
    width: u32,
    height: u32,
    near: f32,
    far: f32,
    profile: bool,
    count_work: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let inputs = [&means, &quats, &scales, &opacities, &features, &background];
    let g = gaussians(inputs, d)?;
    let cam = camera(
        viewmat.as_slice()?,
        k.as_slice()?,
        (width, height),
        (near, far),
    )?;
    let mut times = PassTimes::new();
    let out = timed_call(py, || {
        let ctx = context()?;
        gpu_forward(ctx, &g, &cam, profile.then_some(&mut times), count_work).map_err(raster_err)
    })?;
    forward_dict(py, out, &times)
}

/// A forward render's outputs as `rasterize_forward` returns them.
fn forward_dict<'py>(
    py: Python<'py>,
    out: ForwardOutput,
    times: &PassTimes,
) -> PyResult<Bound<'py, PyDict>> {
    let r = host::time("numpy results", || -> PyResult<_> {
        let r = PyDict::new(py);
        r.set_item("image", PyArray1::from_vec(py, out.image))?;
        r.set_item("depth", PyArray1::from_vec(py, out.depth))?;
        r.set_item("alpha", PyArray1::from_vec(py, out.alpha))?;
        r.set_item("radii", PyArray1::from_vec(py, out.radii))?;
        r.set_item("means2d", PyArray1::from_vec(py, out.means2d))?;
        r.set_item("depths", PyArray1::from_vec(py, out.depths))?;
        r.set_item("intersections", out.intersections)?;
        r.set_item("state", Bound::new(py, RenderState(out.render))?)?;
        Ok(r)
    })?;
    add_times(&r, times)?;
    let work = match out.work {
        Some(w) => {
            let d = PyDict::new(py);
            d.set_item("pairs", w.pairs)?;
            d.set_item("evaluated", w.evaluated)?;
            d.set_item("contributed", w.contributed)?;
            d.set_item("saturated", w.saturated)?;
            d.set_item("tile_size", evsplat_raster::splat::TILE)?;
            Some(d)
        }
        None => None,
    };
    r.set_item("work", work)?;
    Ok(r)
}

/// Start a forward render (arguments as `rasterize_forward`, without profiling) and return
/// without waiting for it: a `PendingRender` that `rasterize_finish` reads back. The device
/// renders while the caller does other work.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (means, quats, scales, opacities, features, d, background, viewmat, k, width, height, near, far, count_work=false))]
fn rasterize_submit<'py>(
    py: Python<'py>,
    means: F32<'py>,
    quats: F32<'py>,
    scales: F32<'py>,
    opacities: F32<'py>,
    features: F32<'py>,
    d: usize,
    background: F32<'py>,
    viewmat: F32<'py>,
    k: F32<'py>,
    width: u32,
    height: u32,
    near: f32,
    far: f32,
    count_work: bool,
) -> PyResult<PendingRender> {
    let inputs = [&means, &quats, &scales, &opacities, &features, &background];
    let g = gaussians(inputs, d)?;
    let cam = camera(
        viewmat.as_slice()?,
        k.as_slice()?,
        (width, height),
        (near, far),
    )?;
    let pending = timed_call(py, || {
        let ctx = context()?;
        gpu_submit(ctx, &g, &cam, count_work).map_err(raster_err)
    })?;
    Ok(PendingRender(std::sync::Mutex::new(Some(pending))))
}

/// Wait for a `PendingRender` and return what `rasterize_forward` would have. Its inputs, as
/// given to `rasterize_submit`, are read only when the render must be redone.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn rasterize_finish<'py>(
    py: Python<'py>,
    pending: &Bound<'py, PendingRender>,
    means: F32<'py>,
    quats: F32<'py>,
    scales: F32<'py>,
    opacities: F32<'py>,
    features: F32<'py>,
    background: F32<'py>,
) -> PyResult<Bound<'py, PyDict>> {
    let taken = (pending.get().0.lock())
        .map_err(|_| PyValueError::new_err("rasterize_finish: a PendingRender poisoned"))?
        .take();
    let pending = taken.ok_or_else(|| PyValueError::new_err("rasterize_finish: read already"))?;
    let inputs = [&means, &quats, &scales, &opacities, &features, &background];
    let g = gaussians(inputs, pending.channels())?;
    let out = timed_call(py, || {
        let ctx = context()?;
        gpu_finish(ctx, pending, &g).map_err(raster_err)
    })?;
    forward_dict(py, out, &PassTimes::new())
}

/// Backward of the render `state`: its inputs (as given to `rasterize_forward`: read only when
/// the render must be redone) and the loss gradients w.r.t. its image, depth and alpha (flat
/// float32) in; gradients of means, quats, scales, opacities, features and means2d out, and the
/// call's host phases in seconds ("host").
/// `atomics` is "float", "cas" or None (the adapter's default, `EVSPLAT_ATOMICS=cas` forces CAS).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (state, means, quats, scales, opacities, features, background, grad_image, grad_depth, grad_alpha, atomics=None, profile=false))]
fn rasterize_backward<'py>(
    py: Python<'py>,
    state: &Bound<'py, RenderState>,
    means: F32<'py>,
    quats: F32<'py>,
    scales: F32<'py>,
    opacities: F32<'py>,
    features: F32<'py>,
    background: F32<'py>,
    grad_image: F32<'py>,
    grad_depth: F32<'py>,
    grad_alpha: F32<'py>,
    atomics: Option<&str>,
    profile: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let mode = match atomics {
        None => None,
        Some(s) if s.eq_ignore_ascii_case("float") => Some(AtomicMode::Float),
        Some(s) if s.eq_ignore_ascii_case("cas") => Some(AtomicMode::Cas),
        Some(s) => {
            return Err(PyValueError::new_err(format!(
                "atomics={s:?} must be \"float\", \"cas\" or None"
            )))
        }
    };
    let grads = OutputGrads {
        image: grad_image.as_slice()?,
        depth: grad_depth.as_slice()?,
        alpha: grad_alpha.as_slice()?,
    };
    let render = &state.get().0;
    let inputs = [&means, &quats, &scales, &opacities, &features, &background];
    let g = gaussians(inputs, render.channels())?;
    let mut times = PassTimes::new();
    let out = timed_call(py, || {
        let ctx = context()?;
        let mode = mode.unwrap_or_else(|| ctx.default_atomic_mode());
        let profile = profile.then_some(&mut times);
        gpu_backward(ctx, render, &g, &grads, mode, profile).map_err(raster_err)
    })?;
    let r = host::time("numpy results", || -> PyResult<_> {
        let r = PyDict::new(py);
        r.set_item("means", PyArray1::from_vec(py, out.means))?;
        r.set_item("quats", PyArray1::from_vec(py, out.quats))?;
        r.set_item("scales", PyArray1::from_vec(py, out.scales))?;
        r.set_item("opacities", PyArray1::from_vec(py, out.opacities))?;
        r.set_item("features", PyArray1::from_vec(py, out.features))?;
        r.set_item("means2d", PyArray1::from_vec(py, out.means2d))?;
        Ok(r)
    })?;
    add_times(&r, &times)?;
    Ok(r)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RenderState>()?;
    m.add_class::<PendingRender>()?;
    m.add_function(wrap_pyfunction!(rasterize_forward, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_submit, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_finish, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_backward, m)?)?;
    Ok(())
}
