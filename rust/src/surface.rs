//! Closest points on a triangle mesh (the scan's surface), for the fits' correspondences.
//!
//! A template vertex matched to its *nearest scan vertex* gets a target that jumps by a sampling
//! step (~0.9 mm) when the template moves across a Voronoi border of the scan's vertices: the
//! fits are then discrete dynamical systems, and a 5e-6 mm change of the input can move the
//! result by millimetres (issue 13, #15). The *closest point on the surface* moves continuously
//! with the query, and so do the quantities read off it by barycentric interpolation: the normal
//! (of the vertex normals) and the boundary share (of the 0/1 boundary flags, 1 on a boundary
//! edge). The fits' weights built from these are continuous too.
//!
//! The search looks at the triangles around the query's `k` nearest vertices: that holds the
//! true closest point whenever its triangle has a corner among them, which on an even scan mesh
//! and a query within a few mm of it is always the case (tests compare with every triangle).

use rayon::prelude::*;

use std::sync::Arc;

use crate::kdtree::KdTree3;
use crate::vec3::{add, dot, scale, sub, Vec3};

/// One closest point: the triangle `face` (`usize::MAX` when the nearest vertices have no
/// triangle: then the nearest vertex itself), barycentric coordinates in the face's vertex
/// order, the point, its distance to the query, the interpolated unit normal and boundary share.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    pub face: usize,
    pub bary: [f64; 3],
    pub point: Vec3,
    pub dist: f64,
    pub normal: Vec3,
    pub boundary: f64,
}

/// A triangle mesh prepared for closest-point queries: KD-tree over the vertices, the
/// vertex→triangle incidence (CSR), unit vertex normals and 0/1 boundary flags.
pub struct Surface {
    tree: Arc<KdTree3>,
    faces: Vec<[usize; 3]>,
    vf_offsets: Vec<usize>,
    vf_faces: Vec<u32>,
    normals: Vec<Vec3>,
    boundary: Vec<f64>,
}

/// Closest point of triangle (a, b, c) to p, as barycentric weights (u, v, w) of (a, b, c)
/// (Ericson, *Real-Time Collision Detection*, 5.1.5: Voronoi regions of the corners and edges).
/// Degenerate triangles fall to an edge or a corner.
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f64; 3] {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = va + vb + vc;
    if !(denom.abs() > 0.0) || !denom.is_finite() {
        // degenerate (zero area): the best of the three edges
        let mut best = [1.0, 0.0, 0.0];
        let mut best_d = f64::INFINITY;
        for (i, j) in [(0usize, 1usize), (1, 2), (0, 2)] {
            let (x, y) = ([a, b, c][i], [a, b, c][j]);
            let e = sub(y, x);
            let ee = dot(e, e);
            let t = if ee > 0.0 { (dot(sub(p, x), e) / ee).clamp(0.0, 1.0) } else { 0.0 };
            let q = add(x, scale(e, t));
            let d = dot(sub(p, q), sub(p, q));
            if d < best_d {
                best_d = d;
                best = [0.0; 3];
                best[i] = 1.0 - t;
                best[j] += t;
            }
        }
        return best;
    }
    let v = vb / denom;
    let w = vc / denom;
    [1.0 - v - w, v, w]
}

impl Surface {
    /// Build from vertices (finite, mm), triangles (indices checked by the caller), unit vertex
    /// normals and boundary flags, all per vertex.
    pub fn new(points: Vec<Vec3>, faces: Vec<[usize; 3]>, normals: Vec<Vec3>, is_boundary: &[bool]) -> Result<Self, String> {
        if points.is_empty() {
            return Err("the surface has no vertices".into());
        }
        let tree = Arc::new(KdTree3::new(points)?);
        Self::with_tree(tree, faces, normals, is_boundary)
    }

    /// [`Surface::new`] on an existing KD-tree of the vertices (shared, not rebuilt: a scan's
    /// tree serves both the nearest-vertex queries and the closest-point ones).
    pub fn with_tree(tree: Arc<KdTree3>, faces: Vec<[usize; 3]>, normals: Vec<Vec3>, is_boundary: &[bool]) -> Result<Self, String> {
        let n = tree.len();
        if n == 0 {
            return Err("the surface has no vertices".into());
        }
        if normals.len() != n || is_boundary.len() != n {
            return Err(format!("normals and boundary flags must have {n} rows"));
        }
        let mut count = vec![0usize; n + 1];
        for f in &faces {
            for &v in f {
                if v >= n {
                    return Err(format!("face index {v} out of range for {n} vertices"));
                }
                count[v + 1] += 1;
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut vf_faces = vec![0u32; count[n]];
        for (fi, f) in faces.iter().enumerate() {
            for &v in f {
                vf_faces[fill[v]] = fi as u32;
                fill[v] += 1;
            }
        }
        let boundary = is_boundary.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
        Ok(Self { tree, faces, vf_offsets: count, vf_faces, normals, boundary })
    }

    /// The vertices.
    pub fn points(&self) -> &[Vec3] {
        self.tree.points()
    }

    /// The unit vertex normals.
    pub fn normals(&self) -> &[Vec3] {
        &self.normals
    }

    /// The boundary flags as 0.0 / 1.0 per vertex.
    pub fn boundary_flags(&self) -> &[f64] {
        &self.boundary
    }

    /// The KD-tree over the vertices.
    pub fn tree(&self) -> &KdTree3 {
        &self.tree
    }

    /// The shared KD-tree over the vertices.
    pub fn shared_tree(&self) -> Arc<KdTree3> {
        self.tree.clone()
    }

    /// Closest point of the surface to `q` among the triangles around its `k` nearest vertices
    /// (ties: the lowest triangle id).
    /// `k` = 0: the nearest vertex itself (face `usize::MAX`), as a nearest-neighbour match.
    pub fn closest(&self, q: &Vec3, k: usize) -> SurfacePoint {
        if k == 0 {
            let (vi, d) = self.tree.nearest(q);
            return SurfacePoint {
                face: usize::MAX,
                bary: [1.0, 0.0, 0.0],
                point: self.points()[vi],
                dist: d,
                normal: self.normals[vi],
                boundary: self.boundary[vi],
            };
        }
        let k = k.min(16).min(self.points().len());
        let mut dist = [0.0f64; 16];
        let mut idx = [0u64; 16];
        self.tree.knn_one(q, k, f64::INFINITY, &mut dist[..k], &mut idx[..k]);
        let pts = self.points();
        // triangles tested so far (a few dozen): each is tested once
        let mut tested = [0u32; 96];
        let mut n_tested = 0usize;
        let mut best: Option<(f64, usize, [f64; 3], Vec3)> = None;
        let mut visit = |fi: usize, best: &mut Option<(f64, usize, [f64; 3], Vec3)>| -> bool {
            if tested[..n_tested].contains(&(fi as u32)) {
                return false;
            }
            if n_tested < tested.len() {
                tested[n_tested] = fi as u32;
                n_tested += 1;
            }
            let f = self.faces[fi];
            let bc = closest_on_triangle(*q, pts[f[0]], pts[f[1]], pts[f[2]]);
            let p = add(add(scale(pts[f[0]], bc[0]), scale(pts[f[1]], bc[1])), scale(pts[f[2]], bc[2]));
            let d = dot(sub(*q, p), sub(*q, p));
            let better = match *best {
                None => true,
                Some((bd, bf, _, _)) => d < bd || (d == bd && fi < bf),
            };
            if better {
                *best = Some((d, fi, bc, p));
            }
            better
        };
        for &vi in &idx[..k] {
            let vi = vi as usize;
            if vi >= pts.len() {
                continue;
            }
            for &fi in &self.vf_faces[self.vf_offsets[vi]..self.vf_offsets[vi + 1]] {
                visit(fi as usize, &mut best);
            }
        }
        // Walk: while the best point lies on an edge or a corner of its triangle, look at the
        // triangles around that edge's or corner's vertices (a point inside a triangle is a local
        // minimum of the distance over the surface: done). The triangles of the k nearest
        // vertices can miss the closest one on an uneven mesh, and the match would then switch
        // discretely as the query moves; the walk reaches it.
        for _ in 0..32 {
            let Some((_, bf, bc, _)) = best else { break };
            if bc.iter().all(|&x| x > 0.0) {
                break;
            }
            let mut improved = false;
            for c in 0..3 {
                if bc[c] > 0.0 {
                    let vi = self.faces[bf][c];
                    for &fi in &self.vf_faces[self.vf_offsets[vi]..self.vf_offsets[vi + 1]] {
                        improved |= visit(fi as usize, &mut best);
                    }
                }
            }
            if !improved {
                break;
            }
        }
        match best {
            Some((d, fi, bc, p)) => {
                let f = self.faces[fi];
                let mut nrm = [0.0; 3];
                let mut b = 0.0;
                for c in 0..3 {
                    nrm = add(nrm, scale(self.normals[f[c]], bc[c]));
                    b += bc[c] * self.boundary[f[c]];
                }
                let len = dot(nrm, nrm).sqrt();
                let normal = if len > 1e-300 { scale(nrm, 1.0 / len) } else { self.normals[f[0]] };
                SurfacePoint { face: fi, bary: bc, point: p, dist: d.sqrt(), normal, boundary: b }
            }
            None => {
                let vi = idx[0] as usize;
                SurfacePoint {
                    face: usize::MAX,
                    bary: [1.0, 0.0, 0.0],
                    point: pts[vi],
                    dist: dist[0],
                    normal: self.normals[vi],
                    boundary: self.boundary[vi],
                }
            }
        }
    }

    /// [`Surface::closest`] of every query, in parallel.
    pub fn closest_all(&self, queries: &[Vec3], k: usize) -> Vec<SurfacePoint> {
        queries.par_iter().with_min_len(128).map(|q| self.closest(q, k)).collect()
    }
}

/// Smooth step 0 → 1 as `x` goes from `lo` to `hi` (C¹, 3t² − 2t³); a hard step when lo == hi.
#[inline]
pub fn smoothstep(lo: f64, hi: f64, x: f64) -> f64 {
    if !(hi > lo) {
        return if x >= hi { 1.0 } else { 0.0 };
    }
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Weight of a match (continuous in its inputs): 1 well inside the tests, 0 outside, and a
/// smooth ramp across each test's band: the normal angle (cosine `cos_ang` against the limit
/// `max_angle_deg` ± `angle_band_deg`), the distance (`max_distance` − `distance_band` to
/// `max_distance`) and, if `reject_boundary`, the boundary share b (weight × (1 − b)).
#[inline]
pub fn match_weight(cos_ang: f64, dist: f64, boundary: f64, max_angle_deg: f64, angle_band_deg: f64, max_distance: f64,
                    distance_band: f64, reject_boundary: bool) -> f64 {
    let hi = (max_angle_deg - angle_band_deg).max(0.0).to_radians().cos();
    let lo = (max_angle_deg + angle_band_deg).min(180.0).to_radians().cos();
    let wn = smoothstep(lo, hi, cos_ang);
    let wd = if max_distance.is_finite() { 1.0 - smoothstep(max_distance - distance_band, max_distance, dist) } else { 1.0 };
    // (a share within rounding of 1, e.g. a point on a boundary edge, counts as 1)
    let wb = if reject_boundary { if boundary >= 1.0 - 1e-12 { 0.0 } else { (1.0 - boundary).clamp(0.0, 1.0) } } else { 1.0 };
    wn * wd * wb
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(q: Vec3, pts: &[Vec3], faces: &[[usize; 3]]) -> f64 {
        faces
            .iter()
            .map(|f| {
                let bc = closest_on_triangle(q, pts[f[0]], pts[f[1]], pts[f[2]]);
                let p = add(add(scale(pts[f[0]], bc[0]), scale(pts[f[1]], bc[1])), scale(pts[f[2]], bc[2]));
                dot(sub(q, p), sub(q, p)).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn triangle_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let close = |x: [f64; 3], y: [f64; 3]| (0..3).all(|i| (x[i] - y[i]).abs() < 1e-12);
        assert!(close(closest_on_triangle([0.2, 0.3, 5.0], a, b, c), [0.5, 0.2, 0.3]));
        assert!(close(closest_on_triangle([-1.0, -1.0, 0.0], a, b, c), [1.0, 0.0, 0.0]));
        assert!(close(closest_on_triangle([2.0, -0.5, 1.0], a, b, c), [0.0, 1.0, 0.0]));
        assert!(close(closest_on_triangle([0.5, -2.0, 0.0], a, b, c), [0.5, 0.5, 0.0]));
        assert!(close(closest_on_triangle([1.0, 1.0, 0.0], a, b, c), [0.0, 0.5, 0.5]));
        // degenerate: a segment
        let bc = closest_on_triangle([0.5, 1.0, 0.0], a, b, [2.0, 0.0, 0.0]);
        assert!((bc[0] + bc[1] + bc[2] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn closest_matches_every_triangle_on_a_bumpy_grid() {
        let (nx, h) = (20usize, 1.0);
        let mut pts = Vec::new();
        for j in 0..nx {
            for i in 0..nx {
                let (x, y) = (i as f64 * h, j as f64 * h);
                pts.push([x + 0.3 * (y * 1.3).sin(), y, 2.0 * (x * 0.4).sin() * (y * 0.3).cos()]);
            }
        }
        let mut faces = Vec::new();
        for j in 0..nx - 1 {
            for i in 0..nx - 1 {
                let v = j * nx + i;
                faces.push([v, v + 1, v + nx + 1]);
                faces.push([v, v + nx + 1, v + nx]);
            }
        }
        let normals = crate::mesh::vertex_normals(&pts, &faces);
        let s = Surface::new(pts.clone(), faces.clone(), normals, &vec![false; pts.len()]).unwrap();
        let mut seed = 1u64;
        for _ in 0..500 {
            let mut r = || {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (seed >> 11) as f64 / (1u64 << 53) as f64
            };
            let q = [2.0 + 15.0 * r(), 2.0 + 15.0 * r(), 4.0 * r() - 2.0];
            let sp = s.closest(&q, 3);
            assert!((sp.dist - brute(q, &pts, &faces)).abs() < 1e-9, "query {q:?}");
            assert!((dot(sp.normal, sp.normal) - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn weights_are_continuous_ramps() {
        assert_eq!(match_weight(1.0, 0.0, 0.0, 80.0, 10.0, 5.0, 1.0, true), 1.0);
        assert_eq!(match_weight(-0.5, 0.0, 0.0, 80.0, 10.0, 5.0, 1.0, true), 0.0);
        assert_eq!(match_weight(1.0, 6.0, 0.0, 80.0, 10.0, 5.0, 1.0, true), 0.0);
        assert!((match_weight(1.0, 4.5, 0.0, 80.0, 10.0, 5.0, 1.0, true) - 0.5).abs() < 1e-12);
        assert!((match_weight(1.0, 0.0, 0.25, 80.0, 10.0, 5.0, 1.0, true) - 0.75).abs() < 1e-12);
        assert_eq!(match_weight(1.0, 0.0, 1.0, 80.0, 10.0, 5.0, 1.0, false), 1.0);
        let c80 = 80f64.to_radians().cos();
        assert!((match_weight(c80, 0.0, 0.0, 80.0, 10.0, 5.0, 1.0, true) - 0.5).abs() < 0.05);
        // a hard step when the bands are 0 (the former behaviour)
        assert_eq!(match_weight(c80 + 1e-9, 4.999, 0.0, 80.0, 0.0, 5.0, 0.0, true), 1.0);
        assert_eq!(match_weight(c80 - 1e-9, 1.0, 0.0, 80.0, 0.0, 5.0, 0.0, true), 0.0);
    }
}
