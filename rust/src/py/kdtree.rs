//! Bindings of `crate::kdtree`: the `KdTree` class (private; wrapped by `facecorr.spatial`).

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyList;

use super::util::{points3, run, value_err};
use crate::kdtree::KdTree3;

/// KD-tree over (N, 3) points; k-nearest and radius queries parallel over the queries.
#[pyclass(frozen, module = "facecorr._core")]
pub struct KdTree {
    pub(crate) inner: Arc<KdTree3>,
}

#[pymethods]
impl KdTree {
    #[new]
    fn new(py: Python<'_>, points: PyReadonlyArray2<'_, f64>) -> PyResult<Self> {
        let p = points3(&points, "points")?;
        let t = run(py, "KdTree", move || KdTree3::new(p))?.map_err(value_err)?;
        Ok(Self { inner: Arc::new(t) })
    }

    #[getter]
    fn n(&self) -> usize {
        self.inner.len()
    }

    /// (dist (Q, k), idx (Q, k) int64); missing neighbours: inf and N.
    fn query<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArray2<'py, f64>,
        k: usize,
        distance_upper_bound: f64,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<i64>>)> {
        if k == 0 {
            return Err(value_err("k must be >= 1"));
        }
        if distance_upper_bound.is_nan() || distance_upper_bound < 0.0 {
            return Err(value_err("distance_upper_bound must be a non-negative number"));
        }
        let qs = points3(&q, "query points")?;
        let nq = qs.len();
        let t = self.inner.clone();
        let (d, i) = run(py, "KdTree.query", move || t.knn(&qs, k, distance_upper_bound))?;
        let i: Vec<i64> = i.into_iter().map(|x| x as i64).collect();
        let d = ndarray::Array2::from_shape_vec((nq, k), d).expect("shape");
        let i = ndarray::Array2::from_shape_vec((nq, k), i).expect("shape");
        Ok((d.into_pyarray(py), i.into_pyarray(py)))
    }

    /// (dist (Q,), idx (Q,) int64): the nearest point of each query, searched within the distance
    /// to its hint (a point index; out of range: no hint). The same answer as query(k=1).
    fn query_hinted<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArray2<'py, f64>,
        hint: numpy::PyReadonlyArray1<'py, i64>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<i64>>)> {
        let qs = points3(&q, "query points")?;
        let h: Vec<u64> = hint.as_array().iter().map(|&x| if x < 0 { u64::MAX } else { x as u64 }).collect();
        if h.len() != qs.len() {
            return Err(value_err(format!("hint must have one index per query point ({}), got {}", qs.len(), h.len())));
        }
        let t = self.inner.clone();
        let (d, i) = run(py, "KdTree.query_hinted", move || t.nearest_hinted(&qs, &h))?;
        let i: Vec<i64> = i.into_iter().map(|x| x as i64).collect();
        Ok((ndarray::Array1::from(d).into_pyarray(py), ndarray::Array1::from(i).into_pyarray(py)))
    }

    /// List (Q) of sorted int64 arrays of the points with distance <= r.
    fn query_ball_point<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArray2<'py, f64>,
        r: f64,
    ) -> PyResult<Bound<'py, PyList>> {
        if !r.is_finite() || r < 0.0 {
            return Err(value_err("r must be a finite non-negative number"));
        }
        let qs = points3(&q, "query points")?;
        let t = self.inner.clone();
        let res = run(py, "KdTree.query_ball_point", move || t.within(&qs, r))?;
        let items: Vec<Bound<'py, PyArray1<i64>>> = res
            .into_iter()
            .map(|v| v.into_iter().map(|x| x as i64).collect::<Vec<_>>().into_pyarray(py))
            .collect();
        PyList::new(py, items)
    }

    /// (count (Q,) int64, sums (Q, C)): per query, the points within distance <= r and the sum
    /// of their rows of `values` (N, C).
    fn ball_sums<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArray2<'py, f64>,
        r: f64,
        values: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArray1<i64>>, Bound<'py, PyArray2<f64>>)> {
        if !r.is_finite() || r < 0.0 {
            return Err(value_err("r must be a finite non-negative number"));
        }
        let qs = points3(&q, "query points")?;
        let v = values.as_array();
        if v.nrows() != self.inner.len() {
            return Err(value_err(format!(
                "values must have one row per tree point ({}), got shape {:?}",
                self.inner.len(),
                v.shape()
            )));
        }
        let c = v.ncols();
        let flat: Vec<f64> = v.iter().copied().collect();
        let nq = qs.len();
        let t = self.inner.clone();
        let (n, s) = run(py, "KdTree.ball_sums", move || t.ball_sums(&qs, r, &flat, c))?;
        let n: Vec<i64> = n.into_iter().map(|x| x as i64).collect();
        let s = ndarray::Array2::from_shape_vec((nq, c), s).expect("shape");
        Ok((ndarray::Array1::from(n).into_pyarray(py), s.into_pyarray(py)))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<KdTree>()?;
    Ok(())
}
