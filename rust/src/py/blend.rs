//! Bindings of `blend`: the normal equations of one expression-fit round.

use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::util::{all_finite, run, value_err};
use crate::blend;

fn rows3<'a>(a: &'a PyReadonlyArray2<'_, f64>, n: usize, name: &str) -> PyResult<&'a [[f64; 3]]> {
    // as_slice also accepts Fortran order, whose rows are not the vertices
    if !a.is_c_contiguous() {
        return Err(value_err(format!("{name} must be C-contiguous")));
    }
    let s = a.as_slice().map_err(|_| value_err(format!("{name} must be C-contiguous")))?;
    if a.shape() != [n, 3] {
        return Err(value_err(format!("{name} must have shape ({n}, 3), got {:?}", a.shape())));
    }
    if s.iter().any(|x| !x.is_finite()) {
        return Err(value_err(format!("{name} contains NaN or infinite values")));
    }
    Ok(s.as_chunks::<3>().0)
}

/// (H (n_x, n_x), g (n_x,), c) of the expression fit's data energy E(x) = xᵀHx − 2gᵀx + c for
/// fixed matches, without the point-to-point shape block (see rust/src/blend.rs).
/// basis: (3N, K) C-contiguous, row 3i + d = coordinate d of vertex i; lin: (3, 3); w: (N,);
/// da, qn, v: (N, 3); lam in [0, 1); rigid: 6 more unknowns (rotation vector, translation).
#[pyfunction]
#[pyo3(signature = (basis, lin, w, da, qn, v, lam, rigid))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn blend_normal_equations<'py>(
    py: Python<'py>, basis: PyReadonlyArray2<'py, f64>, lin: PyReadonlyArray2<'py, f64>, w: PyReadonlyArray1<'py, f64>,
    da: PyReadonlyArray2<'py, f64>, qn: PyReadonlyArray2<'py, f64>, v: PyReadonlyArray2<'py, f64>, lam: f64, rigid: bool,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>, f64)> {
    let ws = w.as_slice().map_err(|_| value_err("w must be C-contiguous"))?;
    let n = ws.len();
    if !basis.is_c_contiguous() {
        return Err(value_err("basis must be C-contiguous"));
    }
    let b = basis.as_slice().map_err(|_| value_err("basis must be C-contiguous"))?;
    let k = basis.shape()[1];
    if basis.shape()[0] != 3 * n || k == 0 {
        return Err(value_err(format!("basis must have shape (3 x {n}, K >= 1), got {:?}", basis.shape())));
    }
    if !all_finite(ws) || !all_finite(b) {
        return Err(value_err("w or basis contains NaN or infinite values"));
    }
    let l = rows3(&lin, 3, "lin")?;
    let lin3 = [l[0], l[1], l[2]];
    let (da, qn, v) = (rows3(&da, n, "da")?, rows3(&qn, n, "qn")?, rows3(&v, n, "v")?);
    if !(0.0..1.0).contains(&lam) {
        return Err(value_err(format!("lam must be in [0, 1), got {lam}")));
    }
    let ne = run(py, "blend_normal_equations", || blend::normal_equations(b, k, &lin3, ws, da, qn, v, lam, rigid))?;
    let h = Array2::from_shape_vec((ne.n_x, ne.n_x), ne.h).expect("shape");
    Ok((h.into_pyarray(py), Array1::from(ne.g).into_pyarray(py), ne.c))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(blend_normal_equations, m)?)?;
    Ok(())
}
