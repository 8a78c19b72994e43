//! Bindings of `crate::fingerprint` as a one-shot function (private; wrapped by
//! `facecorr.descriptors`). The `GeodesicSolver` class has the same method for many calls.

use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::geodesic::{faces3, indices};
use super::spatial::points3;
use super::util::{run, value_err};
use crate::geodesic::GeodesicSolver;

/// Finger Print (C, R) of `centers` for `radii` (mm) on the mesh (vertices, faces).
#[pyfunction]
fn fingerprint<'py>(
    py: Python<'py>,
    vertices: PyReadonlyArray2<'py, f64>,
    faces: PyReadonlyArray2<'py, i64>,
    centers: PyReadonlyArray1<'py, i64>,
    radii: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let v = points3(&vertices, "vertices")?;
    if v.is_empty() {
        return Err(value_err("the mesh has no vertices"));
    }
    let f = faces3(&faces, v.len())?;
    if f.is_empty() {
        return Err(value_err("the mesh has no faces"));
    }
    let c = indices(&centers, v.len(), "center")?;
    let r: Vec<f64> = radii.as_array().to_vec();
    if r.is_empty() {
        return Err(value_err("radii is empty"));
    }
    if !r.iter().all(|x| x.is_finite() && *x > 0.0) {
        return Err(value_err("radii must be finite and > 0"));
    }
    let (nc, nr) = (c.len(), r.len());
    let out = run(py, "fingerprint", move || {
        GeodesicSolver::new(&v, &f).map(|s| crate::fingerprint::fingerprint(&s, &c, &r))
    })?
    .map_err(value_err)?;
    let out = ndarray::Array2::from_shape_vec((nc, nr), out).expect("shape");
    Ok(out.into_pyarray(py))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fingerprint, m)?)?;
    Ok(())
}
