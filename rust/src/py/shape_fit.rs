//! Bindings of `shape_fit` (paper §4.3): the whole fit, and the energy + gradient for tests.

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::surface::Surface;
use super::util::{ids, index_rows, points3, run, value_err};
use crate::shape_fit::{self as core_fit, Adjacency, Correspondences, ScanTarget, ShapeFitOptions, Weights};

/// `d[name] = s.name` for each field name, in order.
macro_rules! set_fields {
    ($d:expr, $s:expr; $($field:ident),+) => {
        $($d.set_item(stringify!($field), $s.$field)?;)+
    };
}

fn anchors(anchor_ids: &PyReadonlyArray1<i64>, pts: &PyReadonlyArray2<f64>, n: usize) -> PyResult<Vec<(usize, [f64; 3])>> {
    let p = points3(pts, "anchor_points")?;
    let n_ids = anchor_ids.as_array().len();
    if n_ids != p.len() {
        return Err(value_err(format!("anchor_ids has {n_ids} entries but anchor_points {} rows", p.len())));
    }
    let i = ids(anchor_ids, n, "anchor_ids")?;
    Ok(i.into_iter().zip(p).collect())
}

fn nonneg(v: f64, name: &str) -> PyResult<f64> {
    if !(v >= 0.0) || v.is_nan() {
        return Err(value_err(format!("{name} must be >= 0, got {v}")));
    }
    Ok(v)
}

/// Energy and gradient of the shape fit for given transforms and fixed correspondences.
/// Returns (total, e_data, e_smooth, e_rigid, e_landmark, grad (N, 12)); parts unweighted.
#[pyfunction]
#[pyo3(signature = (x, points, edges, targets, normals, weights, anchor_ids, anchor_points, w_data, w_smooth, w_rigid, w_landmark))]
#[allow(clippy::too_many_arguments)]
fn shape_fit_energy<'py>(
    py: Python<'py>, x: PyReadonlyArray2<'py, f64>, points: PyReadonlyArray2<'py, f64>, edges: PyReadonlyArray2<'py, i64>,
    targets: PyReadonlyArray2<'py, f64>, normals: PyReadonlyArray2<'py, f64>, weights: PyReadonlyArray1<'py, f64>,
    anchor_ids: PyReadonlyArray1<'py, i64>, anchor_points: PyReadonlyArray2<'py, f64>,
    w_data: f64, w_smooth: f64, w_rigid: f64, w_landmark: f64,
) -> PyResult<(f64, f64, f64, f64, f64, Bound<'py, PyArray2<f64>>)> {
    let p = points3(&points, "points")?;
    let n = p.len();
    let xa = x.as_array();
    if xa.dim() != (n, 12) {
        return Err(value_err(format!("x must have shape ({n}, 12), got {:?}", xa.dim())));
    }
    if xa.iter().any(|v| !v.is_finite()) {
        return Err(value_err("x contains NaN or infinite values"));
    }
    let xv: Vec<f64> = xa.iter().copied().collect();
    let e = index_rows::<2>(&edges, n, "edges")?;
    let t = points3(&targets, "targets")?;
    let nm = points3(&normals, "normals")?;
    let w: Vec<f64> = weights.as_array().to_vec();
    if t.len() != n || nm.len() != n || w.len() != n {
        return Err(value_err(format!("targets, normals and weights must have {n} rows")));
    }
    if w.iter().any(|v| !v.is_finite()) {
        return Err(value_err("weights contains NaN or infinite values"));
    }
    let mut anchor = vec![None; n];
    for (i, q) in anchors(&anchor_ids, &anchor_points, n)? {
        anchor[i] = Some(q);
    }
    let wts = Weights {
        data: nonneg(w_data, "w_data")?,
        smooth: nonneg(w_smooth, "w_smooth")?,
        rigid: nonneg(w_rigid, "w_rigid")?,
        landmark: nonneg(w_landmark, "w_landmark")?,
        tangential: 0.0,
    };
    let (parts, g) = run(py, "shape_fit_energy", move || {
        let adj = Adjacency::from_edges(n, &e);
        let corr = Correspondences { target: t, normal: nm, weight: w, anchor, tangent: Vec::new() };
        let mut g = vec![0.0; 12 * n];
        let parts = core_fit::energy_gradient(&xv, &p, &adj, &corr, wts, &mut g);
        (parts, g)
    })?;
    let g = Array2::from_shape_vec((n, 12), g).expect("shape").into_pyarray(py);
    Ok((parts.total, parts.data, parts.smooth, parts.rigid, parts.landmark, g))
}

/// The shape fit of §4.3 onto `scan` (a `Surface`, e.g. the scan mesh's cached one). Returns (vertices (N, 3), transforms (N, 3, 4), solves: list of dicts).
/// Every option is a required keyword (`template_weight` may be None): the defaults live in one
/// place, the Python dataclass `facecorr.registration.shape.ShapeFitOptions`.
#[pyfunction]
#[pyo3(signature = (template_vertices, template_faces, scan,
    anchor_ids, anchor_points, *, w_data, w_smooth, w_rigid, relax_factor, n_levels, max_icp, relax_tol,
    max_iter, rel_tol, memory, normal_angle_deg, max_distance, reject_boundary, surface_k, angle_band_deg,
    distance_band, w_landmark, template_weight, precondition, feature_lambda, feature_tau, feature_radius, w_tangential))]
#[allow(clippy::too_many_arguments)]
fn shape_fit<'py>(
    py: Python<'py>, template_vertices: PyReadonlyArray2<'py, f64>, template_faces: PyReadonlyArray2<'py, i64>,
    scan: PyRef<'py, Surface>,
    anchor_ids: PyReadonlyArray1<'py, i64>, anchor_points: PyReadonlyArray2<'py, f64>,
    w_data: f64, w_smooth: f64, w_rigid: f64, relax_factor: f64, n_levels: usize, max_icp: usize, relax_tol: f64,
    max_iter: usize, rel_tol: f64, memory: usize, normal_angle_deg: f64, max_distance: f64, reject_boundary: bool,
    surface_k: usize, angle_band_deg: f64, distance_band: f64, w_landmark: f64, template_weight: Option<PyReadonlyArray1<'py, f64>>, precondition: bool,
    feature_lambda: f64, feature_tau: f64, feature_radius: f64, w_tangential: f64,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray3<f64>>, Vec<Bound<'py, PyDict>>)> {
    let tv = points3(&template_vertices, "template_vertices")?;
    let n = tv.len();
    if n == 0 {
        return Err(value_err("template_vertices is empty"));
    }
    let tf = index_rows::<3>(&template_faces, n, "template_faces")?;
    if tf.is_empty() {
        return Err(value_err("template_faces is empty"));
    }
    let surface = scan.inner.clone();
    let anch = anchors(&anchor_ids, &anchor_points, n)?;
    if !(relax_factor > 0.0 && relax_factor <= 1.0) {
        return Err(value_err(format!("relax_factor must be in (0, 1], got {relax_factor}")));
    }
    if n_levels == 0 || max_icp == 0 || max_iter == 0 || memory == 0 {
        return Err(value_err("n_levels, max_icp, max_iter and memory must be >= 1"));
    }
    if !(normal_angle_deg > 0.0 && normal_angle_deg <= 180.0) {
        return Err(value_err(format!("normal_angle_deg must be in (0, 180], got {normal_angle_deg}")));
    }
    if !(max_distance > 0.0) {
        return Err(value_err(format!("max_distance must be > 0, got {max_distance}")));
    }
    let template_weight = match template_weight {
        None => Vec::new(),
        Some(a) => {
            let w = a.as_array().to_vec();
            if w.len() != n {
                return Err(value_err(format!("template_weight must have {n} entries, got {}", w.len())));
            }
            if w.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(value_err("template_weight must be finite and >= 0"));
            }
            w
        }
    };
    let opts = ShapeFitOptions {
        template_weight,
        precondition,
        w_data: nonneg(w_data, "w_data")?,
        w_smooth: nonneg(w_smooth, "w_smooth")?,
        w_rigid: nonneg(w_rigid, "w_rigid")?,
        relax_factor,
        n_levels,
        max_icp,
        relax_tol: nonneg(relax_tol, "relax_tol")?,
        max_iter,
        rel_tol: nonneg(rel_tol, "rel_tol")?,
        memory,
        normal_angle_deg,
        max_distance,
        reject_boundary,
        surface_k: surface_k.min(16),
        angle_band_deg: nonneg(angle_band_deg, "angle_band_deg")?,
        distance_band: nonneg(distance_band, "distance_band")?,
        w_landmark: nonneg(w_landmark, "w_landmark")?,
        feature_lambda: nonneg(feature_lambda, "feature_lambda")?,
        feature_tau: nonneg(feature_tau, "feature_tau")?,
        feature_radius: nonneg(feature_radius, "feature_radius")?,
        w_tangential: nonneg(w_tangential, "w_tangential")?,
    };
    if opts.feature_lambda > 0.0 && !(opts.feature_tau > 0.0 && opts.feature_radius > 0.0) {
        return Err(value_err("feature_tau and feature_radius must be > 0 when feature_lambda > 0"));
    }
    let res = run(py, "shape_fit", move || {
        let scan = ScanTarget::from_surface(surface);
        core_fit::fit(&tv, &tf, &scan, &anch, &opts)
    })?;
    let verts = Array2::from_shape_vec((n, 3), res.vertices.iter().flatten().copied().collect()).expect("shape").into_pyarray(py);
    let tr = Array3::from_shape_vec((n, 3, 4), res.transforms.iter().flatten().copied().collect()).expect("shape").into_pyarray(py);
    let mut solves = Vec::with_capacity(res.solves.len());
    for s in &res.solves {
        let d = PyDict::new(py);
        set_fields!(d, s; level, w_smooth, w_rigid, energy, e_data, e_smooth, e_rigid, e_landmark, n_valid, iterations,
            evaluations, seconds_correspond, seconds_solve);
        solves.push(d);
    }
    Ok((verts, tr, solves))
}

/// `ShapeFitOptions::default()` of the Rust core as a dict (without `template_weight`), for the
/// test that it agrees with the Python dataclass, the source of truth.
#[pyfunction]
fn shape_fit_default_options(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let o = ShapeFitOptions::default();
    let d = PyDict::new(py);
    set_fields!(d, o; w_data, w_smooth, w_rigid, relax_factor, n_levels, max_icp, relax_tol, max_iter, rel_tol, memory,
        normal_angle_deg, max_distance, reject_boundary, surface_k, angle_band_deg, distance_band, w_landmark, precondition,
        feature_lambda, feature_tau, feature_radius, w_tangential);
    Ok(d)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(shape_fit_default_options, m)?)?;
    m.add_function(wrap_pyfunction!(shape_fit_energy, m)?)?;
    m.add_function(wrap_pyfunction!(shape_fit, m)?)?;
    Ok(())
}
