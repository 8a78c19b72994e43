//! Bindings of `crate::fingerprint` as a one-shot function (private; wrapped by
//! `facecorr.descriptors`). The `GeodesicSolver` class (py/geodesic.rs) has the same method for
//! many calls.

use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::geodesic::{check_radii, mesh_u32, vertex_ids};
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
    let (v, f) = mesh_u32(&vertices, &faces, "fingerprint")?;
    let c = vertex_ids(&centers, v.len(), "centers")?;
    let r = check_radii(&radii)?;
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
