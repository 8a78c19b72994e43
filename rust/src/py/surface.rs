//! Bindings of `crate::surface`: the `Surface` class (closest points on a triangle mesh; wrapped
//! by `facecorr.geometry.mesh.Mesh.surface`).

use std::sync::Arc;

use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::util::{index_rows, points3, run, value_err};
use super::kdtree::KdTree;
use crate::surface::Surface as CoreSurface;

/// A triangle mesh prepared for closest-point queries: vertices (N, 3) mm, faces (M, 3),
/// unit vertex normals (N, 3), boundary flags (N,).
#[pyclass(frozen, module = "facecorr._core")]
pub struct Surface {
    pub(crate) inner: Arc<CoreSurface>,
}

#[pymethods]
impl Surface {
    /// `tree`: optional `KdTree` built over exactly these vertices (shared instead of rebuilt).
    #[new]
    #[pyo3(signature = (vertices, faces, normals, is_boundary, tree=None))]
    fn new(
        py: Python<'_>, vertices: PyReadonlyArray2<'_, f64>, faces: PyReadonlyArray2<'_, i64>,
        normals: PyReadonlyArray2<'_, f64>, is_boundary: PyReadonlyArray1<'_, bool>, tree: Option<&KdTree>,
    ) -> PyResult<Self> {
        let v = points3(&vertices, "vertices")?;
        let f = index_rows::<3>(&faces, v.len(), "faces")?;
        let n = points3(&normals, "normals")?;
        let b: Vec<bool> = is_boundary.as_array().to_vec();
        let s = match tree {
            Some(t) => {
                let shared = t.inner.clone();
                if shared.points() != v.as_slice() {
                    return Err(value_err("the KD-tree is not over these vertices"));
                }
                run(py, "Surface", move || CoreSurface::with_tree(shared, f, n, &b))?
            }
            None => run(py, "Surface", move || CoreSurface::new(v, f, n, &b))?,
        }
        .map_err(value_err)?;
        Ok(Self { inner: Arc::new(s) })
    }

    #[getter]
    fn n_vertices(&self) -> usize {
        self.inner.points().len()
    }

    /// Closest surface point of each query (Q, 3) among the triangles around its `k` nearest
    /// vertices (`k` = 0: the nearest vertex). Returns (face (Q,) int64, -1 for a vertex match;
    /// bary (Q, 3); point (Q, 3); dist (Q,); normal (Q, 3) interpolated unit normal; boundary (Q,)
    /// interpolated boundary share in [0, 1]).
    #[allow(clippy::type_complexity)]
    fn closest<'py>(
        &self, py: Python<'py>, q: PyReadonlyArray2<'py, f64>, k: usize,
    ) -> PyResult<(
        Bound<'py, PyArray1<i64>>, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>,
    )> {
        if k > 16 {
            return Err(value_err(format!("k must be <= 16, got {k}")));
        }
        let qs = points3(&q, "query points")?;
        let nq = qs.len();
        let s = self.inner.clone();
        let sp = run(py, "Surface.closest", move || s.closest_all(&qs, k))?;
        let face: Vec<i64> = sp.iter().map(|p| if p.face == usize::MAX { -1 } else { p.face as i64 }).collect();
        let flat = |f: &dyn Fn(&crate::surface::SurfacePoint) -> [f64; 3]| -> Array2<f64> {
            Array2::from_shape_vec((nq, 3), sp.iter().flat_map(f).collect()).expect("shape")
        };
        let bary = flat(&|p| p.bary);
        let point = flat(&|p| p.point);
        let normal = flat(&|p| p.normal);
        let dist = Array1::from_vec(sp.iter().map(|p| p.dist).collect());
        let bnd = Array1::from_vec(sp.iter().map(|p| p.boundary).collect());
        Ok((Array1::from_vec(face).into_pyarray(py), bary.into_pyarray(py), point.into_pyarray(py), dist.into_pyarray(py),
            normal.into_pyarray(py), bnd.into_pyarray(py)))
    }

    /// Normal-aware soft targets (`crate::soft_match`): per query (Q, 3) with unit normal (Q, 3),
    /// its closest surface point among the triangles of its `k` nearest vertices moved along the
    /// tangent plane towards the scan vertices within `radius` mm whose normals match (`lam` mm per
    /// unit of normal difference, temperature `tau` mm). Returns the targets (Q, 3).
    fn soft_targets<'py>(
        &self, py: Python<'py>, q: PyReadonlyArray2<'py, f64>, normals: PyReadonlyArray2<'py, f64>, k: usize,
        radius: f64, lam: f64, tau: f64,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        if k > 16 {
            return Err(value_err(format!("k must be <= 16, got {k}")));
        }
        if !(radius > 0.0 && radius.is_finite() && tau > 0.0 && tau.is_finite() && lam >= 0.0 && lam.is_finite()) {
            return Err(value_err("radius and tau must be positive and lam non-negative (finite)"));
        }
        let qs = points3(&q, "query points")?;
        let ns = points3(&normals, "query normals")?;
        if ns.len() != qs.len() {
            return Err(value_err(format!("query normals must have {} rows, got {}", qs.len(), ns.len())));
        }
        let nq = qs.len();
        let s = self.inner.clone();
        let o = crate::soft_match::SoftMatchOptions { radius, lambda: lam, tau };
        let out = run(py, "Surface.soft_targets", move || {
            let cp = s.closest_all(&qs, k);
            crate::soft_match::soft_targets(&s, &qs, &ns, &cp, &o)
        })?;
        Ok(Array2::from_shape_vec((nq, 3), out.into_iter().flatten().collect()).expect("shape").into_pyarray(py))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Surface>()?;
    Ok(())
}
