//! The native module `evsplat._core`: numpy/torch-facing conversions only; logic lives in the
//! crates it wraps.

use pyo3::prelude::*;

mod blosc;
mod camera;
mod errors;
mod events;
mod formats;
mod gpu;
mod io;
mod raster;
mod sim;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    gpu::register(m)?;
    events::register(m)?;
    formats::register(m)?;
    blosc::register(m)?;
    camera::register(m)?;
    sim::register(m)?;
    io::register(m)?;
    raster::register(m)?;
    Ok(())
}
