//! GPU context queries and the scan kernel.

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use evsplat_raster::{exclusive_scan_u32 as gpu_scan, GpuContext, GpuError};

pub fn gpu_err(e: GpuError) -> PyErr {
    PyRuntimeError::new_err(e.to_string())
}

pub fn context() -> PyResult<&'static GpuContext> {
    GpuContext::global().map_err(gpu_err)
}

/// Adapter name, type, backend, driver, float-atomic and subgroup support and the limits the
/// kernels rely on.
#[pyfunction]
fn adapter_info(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let ctx = py.detach(context)?;
    let d = PyDict::new(py);
    d.set_item("name", &ctx.info.name)?;
    d.set_item("device_type", format!("{:?}", ctx.info.device_type))?;
    d.set_item("backend", format!("{:?}", ctx.info.backend))?;
    d.set_item("driver", &ctx.info.driver)?;
    d.set_item("driver_info", &ctx.info.driver_info)?;
    d.set_item("float32_atomics", ctx.float_atomics)?;
    d.set_item("atomic_mode", format!("{:?}", ctx.default_atomic_mode()))?;
    d.set_item("subgroups", ctx.subgroups)?;
    d.set_item("subgroup_reduce", ctx.subgroup_reduce())?;
    let l = &ctx.limits;
    d.set_item(
        "max_storage_buffer_binding_size",
        l.max_storage_buffer_binding_size,
    )?;
    d.set_item("max_buffer_size", l.max_buffer_size)?;
    d.set_item(
        "max_compute_workgroup_storage_size",
        l.max_compute_workgroup_storage_size,
    )?;
    d.set_item(
        "max_compute_invocations_per_workgroup",
        l.max_compute_invocations_per_workgroup,
    )?;
    d.set_item(
        "max_compute_workgroups_per_dimension",
        l.max_compute_workgroups_per_dimension,
    )?;
    Ok(d)
}

/// Exclusive prefix sum of a u32 array on the GPU (wraps on overflow).
#[pyfunction]
fn exclusive_scan_u32<'py>(
    py: Python<'py>,
    values: PyReadonlyArray1<'py, u32>,
) -> PyResult<Bound<'py, PyArray1<u32>>> {
    let values = values.as_slice()?;
    let out = py.detach(|| gpu_scan(context()?, values).map_err(gpu_err))?;
    Ok(PyArray1::from_vec(py, out))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(adapter_info, m)?)?;
    m.add_function(wrap_pyfunction!(exclusive_scan_u32, m)?)?;
    Ok(())
}
