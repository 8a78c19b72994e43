//! facecorr's Rust core.
//!
//! The algorithms live in plain Rust modules (each with its own `cargo test`); the `py` module,
//! compiled only with the `python` feature, holds the PyO3 bindings: convert, validate, release
//! the GIL, call.

pub mod threads;
pub mod vec3;
pub mod mesh;
pub mod kdtree;
pub mod nearest;
pub mod surface;
pub mod soft_match;
pub mod geodesic;
pub mod fingerprint;
pub mod curvature;
pub mod raster;
pub mod lbfgs;
pub mod shape_fit;
pub mod icp;
pub mod blend;
pub mod ply;
#[doc(hidden)]
pub mod fixtures;

#[cfg(feature = "python")]
mod py;
