//! Bindings of `crate::mesh`: `_core.mesh_*` functions on (V, F) numpy arrays.

use super::util::{faces as faces_from, ids_to_array, on_mesh, run, vec3_to_array};
use crate::mesh as core;
use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;

/// `#[pyfunction] name(vertices, faces)`: one `crate::mesh` kernel on the validated mesh, its
/// result turned into a numpy array by `into_array`.
macro_rules! mesh_kernels {
    ($($(#[doc = $doc:expr])* fn $name:ident -> $array:ty = $kernel:path, $into_array:path;)*) => {$(
        $(#[doc = $doc])*
        #[pyfunction]
        fn $name<'py>(
            py: Python<'py>,
            vertices: PyReadonlyArray2<'py, f64>,
            faces: PyReadonlyArray2<'py, i64>,
        ) -> PyResult<Bound<'py, $array>> {
            let out = on_mesh(py, &vertices, &faces, stringify!($name), $kernel)?;
            Ok($into_array(out).into_pyarray(py))
        }
    )*};
}

mesh_kernels! {
    /// Triangle areas (M,).
    fn mesh_face_areas -> PyArray1<f64> = core::face_areas, Array1::from;
    /// Unit area-weighted vertex normals (N, 3).
    fn mesh_vertex_normals -> PyArray2<f64> = core::vertex_normals, vec3_to_array;
    /// Barycentric vertex areas (N,).
    fn mesh_vertex_areas -> PyArray1<f64> = core::vertex_areas, Array1::from;
    /// Connected-component labels (N,), 0 = largest by area.
    fn mesh_components -> PyArray1<i64> = core::components, ids_to_array;
}

/// Unique undirected edges (E, 2), i < j, sorted lexicographically.
#[pyfunction]
fn mesh_edges<'py>(py: Python<'py>, faces: PyReadonlyArray2<'py, i64>, n_vertices: usize) -> PyResult<Bound<'py, PyArray2<i64>>> {
    let f = faces_from(&faces, n_vertices, "mesh_edges")?;
    let e = run(py, "mesh_edges", || core::edges(&f))?;
    let n = e.len();
    let flat: Vec<i64> = e.into_iter().flatten().map(|i| i as i64).collect();
    Ok(Array2::from_shape_vec((n, 2), flat).expect("shape").into_pyarray(py))
}

/// Sorted boundary vertex ids (B,).
#[pyfunction]
fn mesh_boundary_vertices<'py>(py: Python<'py>, faces: PyReadonlyArray2<'py, i64>, n_vertices: usize) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let f = faces_from(&faces, n_vertices, "mesh_boundary_vertices")?;
    let b = run(py, "mesh_boundary_vertices", || core::boundary_vertices(n_vertices, &f))?;
    Ok(ids_to_array(b).into_pyarray(py))
}

/// (first (G,) int64, group (R,) int64) of the rows of an (R, 3) float64 or int64 array: each
/// group of equal rows' first row (in row order) and each row's group (`crate::mesh::first_of_equal_rows`;
/// floats compare by value: -0.0 equals 0.0; NaN rows are the caller's to refuse).
#[pyfunction]
fn equal_rows<'py>(py: Python<'py>, rows: &Bound<'py, PyAny>) -> PyResult<(Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>)> {
    let keys: Vec<[u64; 3]> = if let Ok(a) = rows.extract::<PyReadonlyArray2<'py, f64>>() {
        let a = a.as_array();
        if a.ncols() != 3 {
            return Err(pyo3::exceptions::PyValueError::new_err("equal_rows: rows must be (R, 3)"));
        }
        a.rows().into_iter().map(|r| [(r[0] + 0.0).to_bits(), (r[1] + 0.0).to_bits(), (r[2] + 0.0).to_bits()]).collect()
    } else if let Ok(a) = rows.extract::<PyReadonlyArray2<'py, i64>>() {
        let a = a.as_array();
        if a.ncols() != 3 {
            return Err(pyo3::exceptions::PyValueError::new_err("equal_rows: rows must be (R, 3)"));
        }
        a.rows().into_iter().map(|r| [r[0] as u64, r[1] as u64, r[2] as u64]).collect()
    } else {
        return Err(pyo3::exceptions::PyTypeError::new_err("equal_rows: rows must be a float64 or int64 (R, 3) array"));
    };
    let (first, group) = run(py, "equal_rows", move || core::first_of_equal_rows(&keys))?;
    Ok((ids_to_array(first).into_pyarray(py), ids_to_array(group).into_pyarray(py)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(equal_rows, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_face_areas, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_vertex_normals, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_vertex_areas, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_edges, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_boundary_vertices, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_components, m)?)?;
    Ok(())
}
