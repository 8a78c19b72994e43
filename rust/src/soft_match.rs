//! Normal-aware soft matches: a tangential pull towards the scan point whose normal is the
//! template vertex's own.
//!
//! A closest point only tells a template vertex how far it is *from* the surface; where on the
//! surface it should sit is left to the regularisers, so a feature of the template (the lip, the
//! eye fissure, the brow ridge) stays wherever the alignment put it, even a few mm beside the same
//! feature of the scan. Where the surface bends, normals tell the features apart: the template's
//! upper-lip vertex, whose normal points forwards and up, belongs where the scan's normal does the
//! same. For a query p with unit normal n (the template's) and its closest surface point q
//! (normal n_q), the soft match is
//!
//!   s = Σ_j w_j v_j / Σ_j w_j,   w_j = exp(−(c_j − c_min) / 2τ²) · (1 − smoothstep(0.8 r, r, |v_j − p|)),
//!   c_j = |v_j − p|² + λ² |n_j − n|²,
//!
//! over the scan vertices v_j (normals n_j, not on the scan's boundary) within `radius` r of p,
//! and the target is q moved by the tangential part of s − q (on q's tangent plane), so that
//! the point-to-plane residual stays the closest point's. On a flat surface, where every normal
//! is the same, the offset is only the sampling's asymmetry about q (~1e-3 mm on a 1 mm grid;
//! 0 where the grid is symmetric about q); the target is continuous in p and n
//! (the cutoff is smooth), so the fits stay continuous in their input (issue 13). No vertex in
//! the ball: the target is q itself.

use rayon::prelude::*;

use crate::surface::{smoothstep, Surface, SurfacePoint};
use crate::vec3::{add, dot, scale, sub, Vec3};

/// Settings of [`soft_target`]: ball radius r (mm), normal weight λ (mm), temperature τ (mm).
#[derive(Clone, Copy, Debug)]
pub struct SoftMatchOptions {
    pub radius: f64,
    pub lambda: f64,
    pub tau: f64,
}

/// The soft target of query `p` (unit normal `n`) whose closest surface point is `cp`.
pub fn soft_target(surface: &Surface, p: &Vec3, n: &Vec3, cp: &SurfacePoint, o: &SoftMatchOptions) -> Vec3 {
    let ids = surface.tree().within_one(p, o.radius);
    let pts = surface.points();
    let nrm = surface.normals();
    let bnd = surface.boundary_flags();
    let lam2 = o.lambda * o.lambda;
    let mut cost = Vec::with_capacity(ids.len());
    let mut cmin = f64::INFINITY;
    for &j in &ids {
        let j = j as usize;
        if bnd[j] > 0.5 {
            cost.push(f64::INFINITY);
            continue;
        }
        let d = sub(pts[j], *p);
        let dn = sub(nrm[j], *n);
        let c = dot(d, d) + lam2 * dot(dn, dn);
        cmin = cmin.min(c);
        cost.push(c);
    }
    if !cmin.is_finite() {
        return cp.point;
    }
    let inv = 1.0 / (2.0 * o.tau * o.tau);
    let mut wsum = 0.0;
    let mut acc = [0.0; 3];
    for (&j, &c) in ids.iter().zip(&cost) {
        if !c.is_finite() {
            continue;
        }
        let v = pts[j as usize];
        let dist = dot(sub(v, *p), sub(v, *p)).sqrt();
        let w = (-(c - cmin) * inv).exp() * (1.0 - smoothstep(0.8 * o.radius, o.radius, dist));
        wsum += w;
        acc = add(acc, scale(v, w));
    }
    if !(wsum > 1e-300) {
        return cp.point;
    }
    let s = scale(acc, 1.0 / wsum);
    let off = sub(s, cp.point);
    let tangential = sub(off, scale(cp.normal, dot(off, cp.normal)));
    add(cp.point, tangential)
}

/// [`soft_target`] of every query, in parallel.
pub fn soft_targets(surface: &Surface, queries: &[Vec3], normals: &[Vec3], closest: &[SurfacePoint],
                    o: &SoftMatchOptions) -> Vec<Vec3> {
    queries
        .par_iter()
        .zip(normals.par_iter())
        .zip(closest.par_iter())
        .with_min_len(64)
        .map(|((p, n), cp)| soft_target(surface, p, n, cp, o))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(nx: usize, h: f64, z: impl Fn(f64, f64) -> f64) -> Surface {
        let (pts, faces) = crate::fixtures::grid(nx, nx, |i, j| {
            let (x, y) = (i as f64 * h, j as f64 * h);
            [x, y, z(x, y)]
        });
        let normals = crate::mesh::vertex_normals(&pts, &faces);
        let n = pts.len();
        Surface::new(pts, faces, normals, &vec![false; n]).unwrap()
    }

    #[test]
    fn flat_surface_gives_the_closest_point() {
        let s = grid(31, 1.0, |_, _| 0.0);
        let o = SoftMatchOptions { radius: 6.0, lambda: 10.0, tau: 2.0 };
        let p = [15.0, 15.0, 0.7];
        let cp = s.closest(&p, 3);
        let t = soft_target(&s, &p, &[0.0, 0.0, 1.0], &cp, &o);
        assert!((t[0] - 15.0).abs() < 1e-9 && (t[1] - 15.0).abs() < 1e-9 && t[2].abs() < 1e-12, "{t:?}");
    }

    #[test]
    fn pulls_towards_the_matching_normal() {
        // a ridge along y at x = 20: a template vertex at x = 17 whose normal is the crest's
        // (straight up) is drawn towards the crest; one with the local normal stays nearly put
        let s = grid(41, 1.0, |x, _| 6.0 * (-(x - 20.0) * (x - 20.0) / 18.0).exp());
        let o = SoftMatchOptions { radius: 8.0, lambda: 10.0, tau: 2.0 };
        let p = [17.0, 20.0, 6.0 * (-9.0f64 / 18.0).exp() + 0.2];
        let cp = s.closest(&p, 3);
        let up = soft_target(&s, &p, &[0.0, 0.0, 1.0], &cp, &o);
        let local = soft_target(&s, &p, &cp.normal, &cp, &o);
        assert!(up[0] > cp.point[0] + 1.0, "crest normal: {up:?} vs closest {:?}", cp.point);
        assert!((local[0] - cp.point[0]).abs() < (up[0] - cp.point[0]).abs() / 3.0, "local normal: {local:?}");
        // the offset is tangential to the closest point's plane
        let d = sub(up, cp.point);
        assert!(dot(d, cp.normal).abs() < 1e-9);
    }

    #[test]
    fn continuous_in_the_query() {
        // a gentle surface and queries 0.5 mm above it, where the closest point itself moves
        // continuously: the soft target must too (a jump of the closest point moves it as well)
        let h = |x: f64, y: f64| 1.5 * (0.2 * x).sin() * (0.15 * y).cos();
        let s = grid(41, 1.0, h);
        let o = SoftMatchOptions { radius: 6.0, lambda: 8.0, tau: 1.5 };
        let n = [0.1, -0.2, 0.97];
        let n = scale(n, 1.0 / dot(n, n).sqrt());
        let mut prev: Option<(Vec3, Vec3)> = None;
        for k in 0..2000 {
            let x = 10.0 + k as f64 * 1e-3;
            let p = [x, 20.0, h(x, 20.0) + 0.5];
            let cp = s.closest(&p, 3);
            let t = soft_target(&s, &p, &n, &cp, &o);
            if let Some((q, c)) = prev {
                let d = sub(t, q);
                let dc = sub(cp.point, c);
                assert!(dot(d, d).sqrt() < 0.01, "jump {} at step {k} (closest point moved {})", dot(d, d).sqrt(), dot(dc, dc).sqrt());
            }
            prev = Some((t, cp.point));
        }
    }
}
