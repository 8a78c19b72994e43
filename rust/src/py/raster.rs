//! Bindings of `crate::raster`: z-buffer rasterization of projected triangles.

use ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::util::{run, value_err};

type RasterOut<'py> = (Bound<'py, PyArray2<i32>>, Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>);

/// rasterize_triangles(uv, depth, triangles, width, height) -> (tri, bary, depth)
///
/// uv: (N, 2) float64 pixel coordinates (u = column, v = row; pixel centres at integers),
/// depth: (N,) float64, triangles: (M, 3) int64 indices into uv.
/// Returns tri (H, W) int32 (-1 = no triangle), bary (H, W, 3) float64, depth (H, W) float64
/// (+inf = no triangle); the nearest triangle wins, exact ties go to the smaller id.
#[pyfunction]
#[pyo3(signature = (uv, depth, triangles, width, height))]
fn rasterize_triangles<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    depth: PyReadonlyArray1<'py, f64>,
    triangles: PyReadonlyArray2<'py, i64>,
    width: usize,
    height: usize,
) -> PyResult<RasterOut<'py>> {
    let uv = uv.as_array();
    let depth = depth.as_array();
    let tris = triangles.as_array();
    if uv.ncols() != 2 {
        return Err(value_err(format!("uv must have shape (N, 2), got (N, {})", uv.ncols())));
    }
    if depth.len() != uv.nrows() {
        return Err(value_err(format!("depth must have shape ({},), got ({},)", uv.nrows(), depth.len())));
    }
    if tris.ncols() != 3 {
        return Err(value_err(format!("triangles must have shape (M, 3), got (M, {})", tris.ncols())));
    }
    if width == 0 || height == 0 || width.saturating_mul(height) > 100_000_000 {
        return Err(value_err(format!("image size {width} x {height} must be positive and at most 1e8 pixels")));
    }
    if !uv.iter().all(|x| x.is_finite()) || !depth.iter().all(|x| x.is_finite()) {
        return Err(value_err("uv and depth must be finite"));
    }
    let n = uv.nrows() as i64;
    if tris.iter().any(|&i| i < 0 || i >= n) {
        return Err(value_err(format!("triangle indices must be in [0, {})", n)));
    }
    let uv_v: Vec<[f64; 2]> = uv.rows().into_iter().map(|r| [r[0], r[1]]).collect();
    let depth_v: Vec<f64> = depth.iter().copied().collect();
    let tris_v: Vec<[usize; 3]> = tris.rows().into_iter().map(|r| [r[0] as usize, r[1] as usize, r[2] as usize]).collect();
    let r = run(py, "rasterize_triangles", || crate::raster::rasterize(&uv_v, &depth_v, &tris_v, width, height))?;
    let tri = Array2::from_shape_vec((height, width), r.tri).map_err(|e| value_err(e.to_string()))?;
    let bary = Array3::from_shape_vec((height, width, 3), r.bary).map_err(|e| value_err(e.to_string()))?;
    let z = Array2::from_shape_vec((height, width), r.depth).map_err(|e| value_err(e.to_string()))?;
    Ok((tri.into_pyarray(py), bary.into_pyarray(py), z.into_pyarray(py)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(rasterize_triangles, m)?)?;
    Ok(())
}
