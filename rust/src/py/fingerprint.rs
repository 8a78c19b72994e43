//! Bindings of `crate::fingerprint` as a one-shot function (private; wrapped by
//! `facecorr.descriptors`). The `GeodesicSolver` class (py/geodesic.rs) has the same method for
//! many calls.

use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::geodesic::{mesh_u32, vertex_ids};
use super::util::{run, value_err};
use crate::geodesic::GeodesicSolver;

/// Finger Print radii: at least one, each finite and > 0.
fn check_radii(radii: &PyReadonlyArray1<'_, f64>) -> PyResult<Vec<f64>> {
    let r: Vec<f64> = radii.as_array().to_vec();
    if r.is_empty() {
        return Err(value_err("radii is empty"));
    }
    if !r.iter().all(|x| x.is_finite() && *x > 0.0) {
        return Err(value_err("radii must be finite and > 0"));
    }
    Ok(r)
}

/// The Finger Print (C, R) of both bindings: validate `centers` (vertex ids in [0, n)) and
/// `radii`, then `run` `fp(centers, radii)` (row-major values, or the core's error) as `what`.
pub(super) fn fingerprint_array<'py>(
    py: Python<'py>, n: usize, centers: &PyReadonlyArray1<'py, i64>, radii: &PyReadonlyArray1<'py, f64>, what: &str,
    fp: impl FnOnce(&[u32], &[f64]) -> Result<Vec<f64>, String> + Send,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let c = vertex_ids(centers, n, "centers")?;
    let r = check_radii(radii)?;
    let out = run(py, what, || fp(&c, &r))?.map_err(value_err)?;
    let out = ndarray::Array2::from_shape_vec((c.len(), r.len()), out).expect("shape");
    Ok(out.into_pyarray(py))
}

/// Finger Print (C, R) of `centers` for `radii` (mm) on the mesh (vertices, faces).
#[pyfunction]
fn fingerprint<'py>(
    py: Python<'py>, vertices: PyReadonlyArray2<'py, f64>, faces: PyReadonlyArray2<'py, i64>,
    centers: PyReadonlyArray1<'py, i64>, radii: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (v, f) = mesh_u32(&vertices, &faces, "fingerprint")?;
    fingerprint_array(py, v.len(), &centers, &radii, "fingerprint", move |c, r| {
        GeodesicSolver::new(&v, &f).map(|s| crate::fingerprint::fingerprint(&s, c, r))
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fingerprint, m)?)?;
    Ok(())
}
