//! Bindings of `crate::geodesic`: the `GeodesicSolver` class (private; wrapped by
//! `facecorr.geodesic`), whose `fingerprint` method calls `crate::fingerprint` on the solver it
//! holds (the one-shot function is in py/fingerprint.rs).

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::fingerprint::fingerprint_array;
use super::util::{ids, mesh, run, value_err};
use crate::geodesic::{GeodesicSolver as Core, Method};

/// A mesh for the geodesic core (u32 indices), validated by `util::mesh`.
pub(super) fn mesh_u32(
    v: &PyReadonlyArray2<'_, f64>,
    f: &PyReadonlyArray2<'_, i64>,
    what: &str,
) -> PyResult<(Vec<[f64; 3]>, Vec<[u32; 3]>)> {
    let (v, f) = mesh(v, f, what)?;
    if v.len() > u32::MAX as usize {
        return Err(value_err(format!("{what}: too many vertices ({})", v.len())));
    }
    Ok((v, f.into_iter().map(|t| t.map(|i| i as u32)).collect()))
}

/// Vertex ids in [0, n) as u32 (`util::ids`).
pub(super) fn vertex_ids(a: &PyReadonlyArray1<'_, i64>, n: usize, name: &str) -> PyResult<Vec<u32>> {
    Ok(ids(a, n, name)?.into_iter().map(|i| i as u32).collect())
}

fn method(s: &str) -> PyResult<Method> {
    match s {
        "fmm" => Ok(Method::Fmm),
        "dijkstra" => Ok(Method::Dijkstra),
        _ => Err(value_err(format!("method must be 'fmm' or 'dijkstra', got {s:?}"))),
    }
}

fn max_dist(m: Option<f64>) -> PyResult<f64> {
    match m {
        None => Ok(f64::INFINITY),
        Some(x) if x.is_nan() || x < 0.0 => Err(value_err("max_distance must be >= 0")),
        Some(x) => Ok(x),
    }
}

/// Geodesic solver precomputed once per mesh.
#[pyclass(frozen, module = "facecorr._core")]
pub struct GeodesicSolver {
    inner: Arc<Core>,
}

#[pymethods]
impl GeodesicSolver {
    #[new]
    fn new(
        py: Python<'_>,
        vertices: PyReadonlyArray2<'_, f64>,
        faces: PyReadonlyArray2<'_, i64>,
    ) -> PyResult<Self> {
        let (v, f) = mesh_u32(&vertices, &faces, "GeodesicSolver")?;
        let s = run(py, "GeodesicSolver", move || Core::new(&v, &f))?.map_err(value_err)?;
        Ok(Self { inner: Arc::new(s) })
    }

    #[getter]
    fn n_vertices(&self) -> usize {
        self.inner.n_vertices()
    }

    #[getter]
    fn n_obtuse_split(&self) -> usize {
        self.inner.n_obtuse_split()
    }

    #[pyo3(signature = (sources, max_distance=None, method="fmm"))]
    fn distances<'py>(
        &self, py: Python<'py>, sources: PyReadonlyArray1<'py, i64>, max_distance: Option<f64>, method: &str,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (src, md, m) = self.query(&sources, max_distance, method)?;
        if src.is_empty() {
            return Err(value_err("sources is empty"));
        }
        let s = self.inner.clone();
        let d = run(py, "GeodesicSolver.distances", move || s.distances(&src, md, m))?;
        Ok(d.into_pyarray(py))
    }

    #[pyo3(signature = (sources, max_distance=None, method="fmm"))]
    fn distance_matrix<'py>(
        &self, py: Python<'py>, sources: PyReadonlyArray1<'py, i64>, max_distance: Option<f64>, method: &str,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (src, md, m) = self.query(&sources, max_distance, method)?;
        let (ns, n) = (src.len(), self.inner.n_vertices());
        let s = self.inner.clone();
        let d = run(py, "GeodesicSolver.distance_matrix", move || s.distance_matrix(&src, md, m))?;
        let d = ndarray::Array2::from_shape_vec((ns, n), d).expect("shape");
        Ok(d.into_pyarray(py))
    }

    /// Finger Print descriptor (C, R) of the given centre vertices and radii (mm).
    fn fingerprint<'py>(
        &self, py: Python<'py>, centers: PyReadonlyArray1<'py, i64>, radii: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let s = self.inner.clone();
        fingerprint_array(py, s.n_vertices(), &centers, &radii, "GeodesicSolver.fingerprint", move |c, r| {
            Ok(crate::fingerprint::fingerprint(&s, c, r))
        })
    }
}

impl GeodesicSolver {
    /// The (sources, max_distance, method) of a distance query, validated.
    fn query(&self, sources: &PyReadonlyArray1<'_, i64>, max_distance: Option<f64>, method: &str) -> PyResult<(Vec<u32>, f64, Method)> {
        let m = self::method(method)?;
        let md = max_dist(max_distance)?;
        let src = vertex_ids(sources, self.inner.n_vertices(), "sources")?;
        Ok((src, md, m))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<GeodesicSolver>()?;
    Ok(())
}
