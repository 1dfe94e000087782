//! Core errors as Python exceptions.

use pyo3::exceptions::PyValueError;
use pyo3::PyErr;

/// A core crate's error (bad input) as a ValueError carrying its one-line message; python/evsplat
/// turns it into an EvsplatError naming the input.
pub fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}
