//! Bindings of `crate::ply`: `_core.read_ply(path)`, the PLY fast path.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2};
use pyo3::prelude::*;

use super::util::{run, vec3_to_array};

/// (vertices (N, 3) float64, faces (M, 3) int64 raw indices, colours (N, 3|4) uint8 or None), or
/// None when the file is not on the fast path (unusual layout, broken, unreadable): the caller
/// then reads it the general way, which also words any error.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn read_ply<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
) -> PyResult<Option<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<i64>>, Option<Bound<'py, PyArray2<u8>>>)>> {
    let out = run(py, "read_ply", move || {
        let data = std::fs::read(&path).ok()?;
        crate::ply::read_ply(&data).ok()
    })?;
    Ok(out.map(|m| {
        let nf = m.faces.len();
        let f = Array2::from_shape_vec((nf, 3), m.faces.into_iter().flatten().collect()).expect("shape");
        let c = m.colors.map(|(c, ch)| {
            let n = c.len() / ch;
            Array2::from_shape_vec((n, ch), c).expect("shape").into_pyarray(py)
        });
        (vec3_to_array(m.vertices).into_pyarray(py), f.into_pyarray(py), c)
    }))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_ply, m)?)?;
    Ok(())
}
