//! Test and bench meshes (not part of the API): one regular grid every test and bench builds on.

use crate::mesh::Face;
use crate::vec3::Vec3;

/// An nx x ny grid of vertices, row by row (`vertex(i, j)` gives vertex j * nx + i), each
/// square split along its (i, j)-(i+1, j+1) diagonal.
pub fn grid(nx: usize, ny: usize, mut vertex: impl FnMut(usize, usize) -> Vec3) -> (Vec<Vec3>, Vec<Face>) {
    let mut v = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            v.push(vertex(i, j));
        }
    }
    let mut f = Vec::with_capacity(2 * nx.saturating_sub(1) * ny.saturating_sub(1));
    for j in 0..ny.saturating_sub(1) {
        for i in 0..nx.saturating_sub(1) {
            let a = j * nx + i;
            f.push([a, a + 1, a + nx + 1]);
            f.push([a, a + nx + 1, a + nx]);
        }
    }
    (v, f)
}

/// Faces with u32 indices, as the geodesic core takes them.
pub fn faces_u32(f: Vec<Face>) -> Vec<[u32; 3]> {
    f.into_iter().map(|t| t.map(|i| i as u32)).collect()
}

/// A reproducible stream of numbers in [0, 1) (64-bit LCG, Knuth's MMIX constants): test and
/// bench inputs without a random-number crate.
pub fn lcg(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64) / ((1u64 << 53) as f64)
    }
}
