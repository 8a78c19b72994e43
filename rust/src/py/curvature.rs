//! Bindings of `crate::curvature`: principal curvatures/directions and umbilics.

use super::util::{ids_to_array, mesh as mesh_from, on_mesh, run, value_err, vec3_to_array};
use crate::mesh::Face;
use crate::vec3::Vec3;
use crate::curvature::{self as core, CurvatureOptions, UmbilicOptions};
use numpy::ndarray::Array1;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

type Curv<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
);

fn check_radius(radius: f64, rings: usize, what: &str) -> PyResult<()> {
    if !radius.is_finite() || radius < 0.0 {
        return Err(value_err(format!("{what}: radius must be finite and >= 0, got {radius}")));
    }
    if rings == 0 || rings > 20 {
        return Err(value_err(format!("{what}: rings must be in [1, 20], got {rings}")));
    }
    Ok(())
}

/// (k1, k2, d1, d2) per vertex by local quadric fitting; see `crate::curvature`.
#[pyfunction]
#[pyo3(signature = (vertices, faces, rings=2, radius=0.0))]
fn principal_curvatures<'py>(
    py: Python<'py>, vertices: PyReadonlyArray2<'py, f64>, faces: PyReadonlyArray2<'py, i64>, rings: usize, radius: f64,
) -> PyResult<Curv<'py>> {
    let what = "principal_curvatures";
    check_radius(radius, rings, what)?;
    let opts = CurvatureOptions { rings, radius };
    let c = on_mesh(py, &vertices, &faces, what, |v, f| core::principal_curvatures(v, f, &opts))?;
    Ok((
        Array1::from(c.k1).into_pyarray(py),
        Array1::from(c.k2).into_pyarray(py),
        vec3_to_array(c.d1).into_pyarray(py),
        vec3_to_array(c.d2).into_pyarray(py),
    ))
}

fn umbilic_options(
    smooth_iters: usize,
    ring: usize,
    threshold: f64,
    eps_rel: f64,
    boundary_rings: usize,
    what: &str,
) -> PyResult<UmbilicOptions> {
    if smooth_iters > 1000 {
        return Err(value_err(format!("{what}: smooth_iters must be <= 1000, got {smooth_iters}")));
    }
    if ring == 0 || ring > 20 {
        return Err(value_err(format!("{what}: ring must be in [1, 20], got {ring}")));
    }
    if !(threshold > 0.0 && threshold <= 1.0) {
        return Err(value_err(format!("{what}: threshold must be in (0, 1], got {threshold}")));
    }
    if !(eps_rel.is_finite() && eps_rel >= 0.0) {
        return Err(value_err(format!("{what}: eps_rel must be finite and >= 0, got {eps_rel}")));
    }
    Ok(UmbilicOptions { smooth_iters, ring, threshold, eps_rel, boundary_rings })
}

fn curvature_field(x: &PyReadonlyArray1<'_, f64>, n: usize, name: &str, what: &str) -> PyResult<Vec<f64>> {
    let a = x.as_array();
    if a.len() != n {
        return Err(value_err(format!("{what}: {name} must have shape ({n},), got ({},)", a.len())));
    }
    if a.iter().any(|v| v.is_infinite()) {
        return Err(value_err(format!("{what}: {name} has infinite values")));
    }
    Ok(a.to_vec())
}

/// The mesh and its principal curvatures (k1, k2) per vertex, validated, for the umbilic kernels.
struct CurvedMesh {
    v: Vec<Vec3>,
    f: Vec<Face>,
    k1: Vec<f64>,
    k2: Vec<f64>,
}

impl CurvedMesh {
    fn new(
        vertices: &PyReadonlyArray2<'_, f64>, faces: &PyReadonlyArray2<'_, i64>,
        k1: &PyReadonlyArray1<'_, f64>, k2: &PyReadonlyArray1<'_, f64>, what: &str,
    ) -> PyResult<Self> {
        let (v, f) = mesh_from(vertices, faces, what)?;
        let k1 = curvature_field(k1, v.len(), "k1", what)?;
        let k2 = curvature_field(k2, v.len(), "k2", what)?;
        Ok(Self { v, f, k1, k2 })
    }
}

/// Umbilicity field (N,) after smoothing; see `crate::curvature`.
#[pyfunction]
#[pyo3(signature = (vertices, faces, k1, k2, smooth_iters=0, eps_rel=0.1))]
fn umbilicity<'py>(
    py: Python<'py>, vertices: PyReadonlyArray2<'py, f64>, faces: PyReadonlyArray2<'py, i64>,
    k1: PyReadonlyArray1<'py, f64>, k2: PyReadonlyArray1<'py, f64>, smooth_iters: usize, eps_rel: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let what = "umbilicity";
    let opts = umbilic_options(smooth_iters, 1, 1.0, eps_rel, 0, what)?;
    let m = CurvedMesh::new(&vertices, &faces, &k1, &k2, what)?;
    let u = run(py, what, || {
        let adj = crate::mesh::Adjacency::new(m.v.len(), &m.f);
        core::umbilicity(&m.k1, &m.k2, &adj, &opts)
    })?;
    Ok(Array1::from(u).into_pyarray(py))
}

/// Umbilic vertex ids (U,), ascending; see `crate::curvature`.
#[pyfunction]
#[pyo3(signature = (vertices, faces, k1, k2, smooth_iters=0, ring=2, threshold=0.5, eps_rel=0.1, boundary_rings=0))]
#[allow(clippy::too_many_arguments)]
fn umbilics<'py>(
    py: Python<'py>, vertices: PyReadonlyArray2<'py, f64>, faces: PyReadonlyArray2<'py, i64>,
    k1: PyReadonlyArray1<'py, f64>, k2: PyReadonlyArray1<'py, f64>,
    smooth_iters: usize, ring: usize, threshold: f64, eps_rel: f64, boundary_rings: usize,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let what = "umbilics";
    let opts = umbilic_options(smooth_iters, ring, threshold, eps_rel, boundary_rings, what)?;
    let m = CurvedMesh::new(&vertices, &faces, &k1, &k2, what)?;
    let ids = run(py, what, || core::umbilics(&m.v, &m.f, &m.k1, &m.k2, &opts))?;
    Ok(ids_to_array(ids).into_pyarray(py))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(principal_curvatures, m)?)?;
    m.add_function(wrap_pyfunction!(umbilicity, m)?)?;
    m.add_function(wrap_pyfunction!(umbilics, m)?)?;
    Ok(())
}
