//! Bindings of `crate::geodesic` and `crate::fingerprint`: the `GeodesicSolver` class (private;
//! wrapped by `facecorr.geodesic`).

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::spatial::points3;
use super::util::{run, value_err};
use crate::geodesic::{GeodesicSolver as Core, Method};

/// Read (M, 3) int64 faces with indices in [0, n).
pub(crate) fn faces3(a: &PyReadonlyArray2<'_, i64>, n: usize) -> PyResult<Vec<[u32; 3]>> {
    let a = a.as_array();
    if a.ncols() != 3 {
        return Err(value_err(format!("faces must have shape (m, 3), got (m, {})", a.ncols())));
    }
    let mut out = Vec::with_capacity(a.nrows());
    for (i, r) in a.rows().into_iter().enumerate() {
        let mut f = [0u32; 3];
        for k in 0..3 {
            if r[k] < 0 || r[k] as u64 >= n as u64 {
                return Err(value_err(format!(
                    "face {i} has vertex index {} out of range [0, {n})",
                    r[k]
                )));
            }
            f[k] = r[k] as u32;
        }
        out.push(f);
    }
    Ok(out)
}

/// Read vertex indices in [0, n); `what` names them in errors.
pub(crate) fn indices(a: &PyReadonlyArray1<'_, i64>, n: usize, what: &str) -> PyResult<Vec<u32>> {
    a.as_array()
        .iter()
        .map(|&x| {
            if x < 0 || x as u64 >= n as u64 {
                Err(value_err(format!("{what} index {x} out of range [0, {n})")))
            } else {
                Ok(x as u32)
            }
        })
        .collect()
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
        let v = points3(&vertices, "vertices")?;
        if v.is_empty() {
            return Err(value_err("the mesh has no vertices"));
        }
        let f = faces3(&faces, v.len())?;
        if f.is_empty() {
            return Err(value_err("the mesh has no faces"));
        }
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
        &self,
        py: Python<'py>,
        sources: PyReadonlyArray1<'py, i64>,
        max_distance: Option<f64>,
        method: &str,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let m = self::method(method)?;
        let md = max_dist(max_distance)?;
        let src = indices(&sources, self.inner.n_vertices(), "source")?;
        if src.is_empty() {
            return Err(value_err("sources is empty"));
        }
        let s = self.inner.clone();
        let d = run(py, "GeodesicSolver.distances", move || s.distances(&src, md, m))?;
        Ok(d.into_pyarray(py))
    }

    #[pyo3(signature = (sources, max_distance=None, method="fmm"))]
    fn distance_matrix<'py>(
        &self,
        py: Python<'py>,
        sources: PyReadonlyArray1<'py, i64>,
        max_distance: Option<f64>,
        method: &str,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let m = self::method(method)?;
        let md = max_dist(max_distance)?;
        let n = self.inner.n_vertices();
        let src = indices(&sources, n, "source")?;
        let ns = src.len();
        let s = self.inner.clone();
        let d = run(py, "GeodesicSolver.distance_matrix", move || s.distance_matrix(&src, md, m))?;
        let d = ndarray::Array2::from_shape_vec((ns, n), d).expect("shape");
        Ok(d.into_pyarray(py))
    }

    /// Finger Print descriptor (C, R) of the given centre vertices and radii (mm).
    fn fingerprint<'py>(
        &self,
        py: Python<'py>,
        centers: PyReadonlyArray1<'py, i64>,
        radii: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let c = indices(&centers, self.inner.n_vertices(), "center")?;
        let r: Vec<f64> = radii.as_array().to_vec();
        if r.is_empty() {
            return Err(value_err("radii is empty"));
        }
        if !r.iter().all(|x| x.is_finite() && *x > 0.0) {
            return Err(value_err("radii must be finite and > 0"));
        }
        let (nc, nr) = (c.len(), r.len());
        let s = self.inner.clone();
        let out = run(py, "GeodesicSolver.fingerprint", move || {
            crate::fingerprint::fingerprint(&s, &c, &r)
        })?;
        let out = ndarray::Array2::from_shape_vec((nc, nr), out).expect("shape");
        Ok(out.into_pyarray(py))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<GeodesicSolver>()?;
    Ok(())
}
