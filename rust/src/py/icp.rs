//! Bindings of `crate::icp`: trimmed rigid ICP onto a `Surface` (wrapped by
//! `facecorr.landmarks.pose.surface_icp`).

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::prelude::*;

use super::surface::Surface;
use super::util::{points3, run, value_err};

/// Trimmed point-to-plane rigid ICP of `points` (P, 3) onto the `surface`'s vertices and
/// normals from S starting poses x -> R x + t (`rotations` (S, 3, 3), `translations` (S, 3)),
/// the starts in parallel (`crate::icp`; `facecorr.landmarks.pose.trimmed_icp` is the numpy
/// reference). `prev` (S,): to resume earlier runs from their final poses, their returned
/// `prev` (None: fresh starts). Returns (rotations (S, 3, 3), translations (S, 3), trimmed RMS
/// (S,) mm, distances (S, P) mm at the final poses, pose updates (S,) int64, prev (S,) mm).
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
#[pyfunction]
#[pyo3(signature = (surface, points, rotations, translations, iters, keep, tol, prev=None))]
fn trimmed_icp<'py>(
    py: Python<'py>, surface: PyRef<'py, Surface>, points: PyReadonlyArray2<'py, f64>, rotations: PyReadonlyArray3<'py, f64>,
    translations: PyReadonlyArray2<'py, f64>, iters: usize, keep: f64, tol: f64, prev: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<(
    Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<f64>>,
)> {
    let pts = points3(&points, "points")?;
    if pts.is_empty() {
        return Err(value_err("points is empty"));
    }
    let ts = points3(&translations, "translations")?;
    let r = rotations.as_array();
    if r.ndim() != 3 || r.shape()[0] != ts.len() || r.shape()[1] != 3 || r.shape()[2] != 3 {
        return Err(value_err(format!("rotations must have shape ({}, 3, 3), got {:?}", ts.len(), r.shape())));
    }
    if !r.iter().all(|v| v.is_finite()) {
        return Err(value_err("rotations hold NaN or infinite values"));
    }
    if !(keep > 0.0 && keep <= 1.0) || tol.is_nan() {
        return Err(value_err(format!("keep must be in (0, 1] and tol a number (-inf: never stop early), got {keep}, {tol}")));
    }
    let prevs: Vec<f64> = match &prev {
        Some(p) => p.as_array().iter().copied().collect(),
        None => Vec::new(),
    };
    if prev.is_some() && prevs.len() != ts.len() {
        return Err(value_err(format!("prev must have {} values, got {}", ts.len(), prevs.len())));
    }
    if prevs.iter().any(|v| v.is_nan()) {
        return Err(value_err("prev holds NaN"));
    }
    let starts: Vec<crate::icp::Pose> = (0..ts.len())
        .map(|s| {
            let mut m = [[0.0; 3]; 3];
            for (i, row) in m.iter_mut().enumerate() {
                for (j, v) in row.iter_mut().enumerate() {
                    *v = r[[s, i, j]];
                }
            }
            (m, ts[s])
        })
        .collect();
    let surf = surface.inner.clone();
    let out = run(py, "trimmed_icp", move || {
        crate::icp::trimmed_icp_many(&pts, surf.tree(), surf.normals(), &starts, iters, keep, tol, &prevs)
    })?;
    let (ns, np) = (out.len(), points.as_array().nrows());
    let rot = Array3::from_shape_vec((ns, 3, 3), out.iter().flat_map(|o| o.pose.0.into_iter().flatten()).collect()).expect("shape");
    let tr = Array2::from_shape_vec((ns, 3), out.iter().flat_map(|o| o.pose.1).collect()).expect("shape");
    let rms = Array1::from_vec(out.iter().map(|o| o.rms).collect());
    let dist = Array2::from_shape_vec((ns, np), out.iter().flat_map(|o| o.dist.iter().copied()).collect()).expect("shape");
    let it = Array1::from_vec(out.iter().map(|o| o.iterations as i64).collect());
    let pv = Array1::from_vec(out.iter().map(|o| o.prev).collect());
    Ok((rot.into_pyarray(py), tr.into_pyarray(py), rms.into_pyarray(py), dist.into_pyarray(py), it.into_pyarray(py),
        pv.into_pyarray(py)))
}


pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(trimmed_icp, m)?)?;
    Ok(())
}
