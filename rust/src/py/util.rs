//! Shared helpers for the bindings.

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Number of threads facecorr's pool uses (`FACECORR_THREADS`, default 2).
#[pyfunction]
pub fn n_threads() -> usize {
    crate::threads::n_threads()
}

/// Release the GIL, run `f` in facecorr's thread pool, and map a panic to a `RuntimeError`
/// naming the kernel (a panic is a bug of ours, never the user's, and must not abort Python).
pub fn run<R: Send, F: FnOnce() -> R + Send>(py: Python<'_>, what: &str, f: F) -> PyResult<R> {
    let out = py.detach(|| catch_unwind(AssertUnwindSafe(|| crate::threads::install(f))));
    out.map_err(|e| {
        let msg = e
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "unknown panic".into());
        PyRuntimeError::new_err(format!("facecorr internal error in {what}: {msg}"))
    })
}

/// A `ValueError` with a one-line message.
pub fn value_err(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(msg.into())
}
