//! Shared helpers for the bindings: running a kernel (`run`, `on_mesh`), errors, and the one validator of
//! (N, 3) vertex and (M, K) index arrays every binding uses.

use numpy::ndarray::{Array1, Array2};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};

use crate::mesh::Face;
use crate::vec3::Vec3;

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

/// True when every number of `xs` is finite. x − x is 0 for a finite x and NaN for ±inf or NaN,
/// so one sum per lane tells; eight lanes let it vectorise (a per-element test with early exit
/// does not: on the expression fit's 7 MB shape basis it took ~0.5 ms per call).
pub fn all_finite(xs: &[f64]) -> bool {
    let mut acc = [0.0f64; 8];
    let chunks = xs.chunks_exact(8);
    let tail = chunks.remainder();
    for c in chunks {
        for l in 0..8 {
            acc[l] += c[l] - c[l];
        }
    }
    acc.iter().all(|a| *a == 0.0) && tail.iter().all(|x| x.is_finite())
}

/// A `ValueError` with a one-line message.
pub fn value_err(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(msg.into())
}

// ---- the one validator of vertex / index arrays ------------------------------------------------
// Messages are one line and name the array; callers match on "shape", "NaN or infinite",
// "holds index", "out of range" / "outside", "no vertices" / "no faces".

/// (N, 3) float64 -> points, checking the shape and that every coordinate is finite.
/// `name` names the array in errors (e.g. "template_vertices", "mesh_edges faces").
pub fn points3(a: &PyReadonlyArray2<'_, f64>, name: &str) -> PyResult<Vec<Vec3>> {
    let a = a.as_array();
    if a.ncols() != 3 {
        return Err(value_err(format!("{name} must have shape (N, 3), got {:?}", a.shape())));
    }
    let out: Vec<Vec3> = a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
    if let Some(i) = out.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(value_err(format!("{name}: vertex {i} has a NaN or infinite coordinate")));
    }
    Ok(out)
}

/// (M, K) int64 -> rows of indices, checking the shape and that every index is in [0, n).
pub fn index_rows<const K: usize>(a: &PyReadonlyArray2<'_, i64>, n: usize, name: &str) -> PyResult<Vec<[usize; K]>> {
    let a = a.as_array();
    if a.ncols() != K {
        return Err(value_err(format!("{name} must have shape (M, {K}), got {:?}", a.shape())));
    }
    let mut out = Vec::with_capacity(a.nrows());
    for (k, r) in a.rows().into_iter().enumerate() {
        let mut t = [0usize; K];
        for (j, t) in t.iter_mut().enumerate() {
            *t = index(r[j], n, name, Some(k))?;
        }
        out.push(t);
    }
    Ok(out)
}

/// (L,) int64 -> indices in [0, n).
pub fn ids(a: &PyReadonlyArray1<'_, i64>, n: usize, name: &str) -> PyResult<Vec<usize>> {
    a.as_array().iter().map(|&x| index(x, n, name, None)).collect()
}

fn index(x: i64, n: usize, name: &str, row: Option<usize>) -> PyResult<usize> {
    if x < 0 || x as u64 >= n as u64 {
        let at = row.map(|k| format!(" in row {k}")).unwrap_or_default();
        return Err(value_err(format!("{name} holds index {x}{at}: out of range, outside [0, {n})")));
    }
    Ok(x as usize)
}

/// (M, 3) triangles into `n` vertices, at least one.
pub fn faces(f: &PyReadonlyArray2<'_, i64>, n: usize, what: &str) -> PyResult<Vec<Face>> {
    let out = index_rows::<3>(f, n, &format!("{what} faces"))?;
    if out.is_empty() {
        return Err(value_err(format!("{what}: the mesh has no faces")));
    }
    Ok(out)
}

/// The (V, F) of a triangle mesh: at least one vertex and one face; `what` (the kernel) prefixes
/// the errors.
pub fn mesh(v: &PyReadonlyArray2<'_, f64>, f: &PyReadonlyArray2<'_, i64>, what: &str) -> PyResult<(Vec<Vec3>, Vec<Face>)> {
    let vv = points3(v, &format!("{what} vertices"))?;
    if vv.is_empty() {
        return Err(value_err(format!("{what}: the mesh has no vertices")));
    }
    let ff = faces(f, vv.len(), what)?;
    Ok((vv, ff))
}

/// Validate (V, F) as `mesh` does, then run `kernel` on it as `run` does; `what` names both.
pub fn on_mesh<R: Send>(
    py: Python<'_>, vertices: &PyReadonlyArray2<'_, f64>, faces: &PyReadonlyArray2<'_, i64>, what: &str,
    kernel: impl FnOnce(&[Vec3], &[Face]) -> R + Send,
) -> PyResult<R> {
    let (v, f) = mesh(vertices, faces, what)?;
    run(py, what, || kernel(&v, &f))
}

/// Vertex ids -> an int64 array.
pub fn ids_to_array(x: Vec<usize>) -> Array1<i64> {
    x.into_iter().map(|i| i as i64).collect()
}

/// Points -> an (N, 3) array.
pub fn vec3_to_array(x: Vec<Vec3>) -> Array2<f64> {
    let n = x.len();
    Array2::from_shape_vec((n, 3), x.into_iter().flatten().collect()).expect("shape")
}
