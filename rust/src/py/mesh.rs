//! Bindings of `crate::mesh`: `_core.mesh_*` functions on (V, F) numpy arrays.
//! Also the (V, F) conversion + validation helpers the other mesh-based bindings reuse.

use super::util::{run, value_err};
use crate::mesh::{self as core, Face, Vec3};
use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;

/// (N, 3) float64 -> Vec<[f64; 3]>, checking shape and finiteness.
pub(super) fn vertices_from(v: &PyReadonlyArray2<'_, f64>, what: &str) -> PyResult<Vec<Vec3>> {
    let a = v.as_array();
    if a.ncols() != 3 {
        return Err(value_err(format!("{what}: vertices must have shape (N, 3), got {:?}", a.shape())));
    }
    if a.nrows() == 0 {
        return Err(value_err(format!("{what}: the mesh has no vertices")));
    }
    let out: Vec<Vec3> = a.outer_iter().map(|r| [r[0], r[1], r[2]]).collect();
    if let Some(i) = out.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(value_err(format!("{what}: vertex {i} has a NaN or infinite coordinate")));
    }
    Ok(out)
}

/// (M, 3) int64 -> Vec<[usize; 3]>, checking shape and that indices are in [0, n).
pub(super) fn faces_from(f: &PyReadonlyArray2<'_, i64>, n: usize, what: &str) -> PyResult<Vec<Face>> {
    let a = f.as_array();
    if a.ncols() != 3 {
        return Err(value_err(format!("{what}: faces must have shape (M, 3), got {:?}", a.shape())));
    }
    if a.nrows() == 0 {
        return Err(value_err(format!("{what}: the mesh has no faces")));
    }
    let mut out = Vec::with_capacity(a.nrows());
    for (k, r) in a.outer_iter().enumerate() {
        let mut t = [0usize; 3];
        for j in 0..3 {
            let x = r[j];
            if x < 0 || x as u64 >= n as u64 {
                return Err(value_err(format!(
                    "{what}: face {k} has vertex index {x} outside [0, {}]",
                    n as i64 - 1
                )));
            }
            t[j] = x as usize;
        }
        out.push(t);
    }
    Ok(out)
}

/// Both, for the common (V, F) signature.
pub(super) fn mesh_from(
    v: &PyReadonlyArray2<'_, f64>,
    f: &PyReadonlyArray2<'_, i64>,
    what: &str,
) -> PyResult<(Vec<Vec3>, Vec<Face>)> {
    let vv = vertices_from(v, what)?;
    let ff = faces_from(f, vv.len(), what)?;
    Ok((vv, ff))
}

pub(super) fn vec3_to_array(x: Vec<Vec3>) -> Array2<f64> {
    let n = x.len();
    Array2::from_shape_vec((n, 3), x.into_iter().flatten().collect()).expect("shape")
}

fn usize_to_i64(x: Vec<usize>) -> Array1<i64> {
    x.into_iter().map(|i| i as i64).collect()
}

/// Triangle areas (M,).
#[pyfunction]
fn mesh_face_areas<'py>(
    py: Python<'py>,
    vertices: PyReadonlyArray2<'py, f64>,
    faces: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let (v, f) = mesh_from(&vertices, &faces, "mesh_face_areas")?;
    let a = run(py, "mesh_face_areas", || core::face_areas(&v, &f))?;
    Ok(Array1::from(a).into_pyarray(py))
}

/// Unit area-weighted vertex normals (N, 3).
#[pyfunction]
fn mesh_vertex_normals<'py>(
    py: Python<'py>,
    vertices: PyReadonlyArray2<'py, f64>,
    faces: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (v, f) = mesh_from(&vertices, &faces, "mesh_vertex_normals")?;
    let n = run(py, "mesh_vertex_normals", || core::vertex_normals(&v, &f))?;
    Ok(vec3_to_array(n).into_pyarray(py))
}

/// Barycentric vertex areas (N,).
#[pyfunction]
fn mesh_vertex_areas<'py>(
    py: Python<'py>,
    vertices: PyReadonlyArray2<'py, f64>,
    faces: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let (v, f) = mesh_from(&vertices, &faces, "mesh_vertex_areas")?;
    let a = run(py, "mesh_vertex_areas", || core::vertex_areas(&v, &f))?;
    Ok(Array1::from(a).into_pyarray(py))
}

/// Unique undirected edges (E, 2), i < j, sorted lexicographically.
#[pyfunction]
fn mesh_edges<'py>(
    py: Python<'py>,
    faces: PyReadonlyArray2<'py, i64>,
    n_vertices: usize,
) -> PyResult<Bound<'py, PyArray2<i64>>> {
    let f = faces_from(&faces, n_vertices, "mesh_edges")?;
    let e = run(py, "mesh_edges", || core::edges(&f))?;
    let n = e.len();
    let flat: Vec<i64> = e.into_iter().flatten().map(|i| i as i64).collect();
    Ok(Array2::from_shape_vec((n, 2), flat).expect("shape").into_pyarray(py))
}

/// Sorted boundary vertex ids (B,).
#[pyfunction]
fn mesh_boundary_vertices<'py>(
    py: Python<'py>,
    faces: PyReadonlyArray2<'py, i64>,
    n_vertices: usize,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let f = faces_from(&faces, n_vertices, "mesh_boundary_vertices")?;
    let b = run(py, "mesh_boundary_vertices", || core::boundary_vertices(n_vertices, &f))?;
    Ok(usize_to_i64(b).into_pyarray(py))
}

/// Connected-component labels (N,), 0 = largest by area.
#[pyfunction]
fn mesh_components<'py>(
    py: Python<'py>,
    vertices: PyReadonlyArray2<'py, f64>,
    faces: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let (v, f) = mesh_from(&vertices, &faces, "mesh_components")?;
    let c = run(py, "mesh_components", || core::components(&v, &f))?;
    Ok(usize_to_i64(c).into_pyarray(py))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(mesh_face_areas, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_vertex_normals, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_vertex_areas, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_edges, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_boundary_vertices, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_components, m)?)?;
    Ok(())
}
