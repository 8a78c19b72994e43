//! Bindings of `crate::mesh`: `_core.mesh_*` functions on (V, F) numpy arrays.

use super::util::{faces as faces_from, mesh as mesh_from, run, vec3_to_array};
use crate::mesh as core;
use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;

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
