//! PyO3 bindings, one file per core module, named as it (py/kdtree.rs binds kdtree.rs, ...);
//! util.rs holds what they share (running a kernel, the vertex / index array validator). Each
//! binding converts and validates its arguments, releases the GIL and calls the core through
//! `util::run`, which also turns a Rust panic into a Python `RuntimeError` instead of a crash.

use pyo3::prelude::*;

mod util;
mod mesh;
mod kdtree;
mod surface;
mod geodesic;
mod fingerprint;
mod curvature;
mod raster;
mod shape_fit;
mod icp;
mod blend;
mod ply;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(util::n_threads, m)?)?;
    mesh::register(m)?;
    kdtree::register(m)?;
    surface::register(m)?;
    geodesic::register(m)?;
    fingerprint::register(m)?;
    curvature::register(m)?;
    raster::register(m)?;
    shape_fit::register(m)?;
    icp::register(m)?;
    blend::register(m)?;
    ply::register(m)?;
    Ok(())
}
