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
    tree: KdTree3,
    faces: Vec<[usize; 3]>,
    tris: Vec<Tri>,
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

/// A triangle prepared for point queries: corner a, edges ab, ac and their dot products.
#[derive(Clone, Copy, Debug)]
struct Tri {
    a: Vec3,
    ab: Vec3,
    ac: Vec3,
    aa: f64,
    abac: f64,
    cc: f64,
}

impl Tri {
    fn new(a: Vec3, b: Vec3, c: Vec3) -> Self {
        let (ab, ac) = (sub(b, a), sub(c, a));
        Self { a, ab, ac, aa: dot(ab, ab), abac: dot(ab, ac), cc: dot(ac, ac) }
    }

    /// Barycentric weights of the closest point to p and its squared distance: Ericson's test
    /// with the other corners' dot products derived from two (bp = ap − ab, cp = ap − ac).
    #[inline]
    fn closest(&self, p: Vec3) -> ([f64; 3], f64) {
        let ap = sub(p, self.a);
        let d1 = dot(self.ab, ap);
        let d2 = dot(self.ac, ap);
        let d3 = d1 - self.aa;
        let d4 = d2 - self.abac;
        let d5 = d1 - self.abac;
        let d6 = d2 - self.cc;
        let (v, w) = if d1 <= 0.0 && d2 <= 0.0 {
            (0.0, 0.0)
        } else if d3 >= 0.0 && d4 <= d3 {
            (1.0, 0.0)
        } else if d6 >= 0.0 && d5 <= d6 {
            (0.0, 1.0)
        } else {
            let vc = d1 * d4 - d3 * d2;
            let vb = d5 * d2 - d1 * d6;
            let va = d3 * d6 - d5 * d4;
            if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
                (d1 / (d1 - d3), 0.0)
            } else if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
                (0.0, d2 / (d2 - d6))
            } else if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
                let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
                (1.0 - w, w)
            } else {
                let denom = va + vb + vc;
                if !(denom > 0.0) || !denom.is_finite() {
                    // degenerate (zero area): the general routine's edge search
                    let bc = closest_on_triangle(p, self.a, add(self.a, self.ab), add(self.a, self.ac));
                    let e = sub(ap, add(scale(self.ab, bc[1]), scale(self.ac, bc[2])));
                    return (bc, dot(e, e));
                }
                (vb / denom, vc / denom)
            }
        };
        let e = sub(ap, add(scale(self.ab, v), scale(self.ac, w)));
        ([1.0 - v - w, v, w], dot(e, e))
    }
}

/// Distance (mm) within which a warm-started walk is trusted without a KD-tree search.
pub const WARM_TRUST: f64 = 1.0;

/// One query's search state: the triangles tested so far (each once) and the best one
/// (squared distance, triangle, barycentric weights).
struct Search<'a> {
    s: &'a Surface,
    q: Vec3,
    tested: [u32; 96],
    n_tested: usize,
    best: Option<(f64, usize, [f64; 3])>,
}

impl Search<'_> {
    /// Test triangle `fi`; true if it is the new best.
    fn visit(&mut self, fi: usize) -> bool {
        if self.tested[..self.n_tested].contains(&(fi as u32)) {
            return false;
        }
        if self.n_tested < self.tested.len() {
            self.tested[self.n_tested] = fi as u32;
            self.n_tested += 1;
        }
        let (bc, d) = self.s.tris[fi].closest(self.q);
        let better = match self.best {
            None => true,
            Some((bd, bf, _)) => d < bd || (d == bd && fi < bf),
        };
        if better {
            self.best = Some((d, fi, bc));
        }
        better
    }

    fn around_vertex(&mut self, vi: usize) -> bool {
        let s = self.s;
        let mut improved = false;
        for &fi in &s.vf_faces[s.vf_offsets[vi]..s.vf_offsets[vi + 1]] {
            improved |= self.visit(fi as usize);
        }
        improved
    }

    /// The triangles around the query's k nearest vertices.
    fn around_nearest(&mut self, k: usize) {
        let mut dist = [0.0f64; 16];
        let mut idx = [0u64; 16];
        self.s.tree.knn_one(&self.q, k, f64::INFINITY, &mut dist[..k], &mut idx[..k]);
        for &vi in &idx[..k] {
            if (vi as usize) < self.s.points().len() {
                self.around_vertex(vi as usize);
            }
        }
    }

    /// While the best point lies on an edge or a corner of its triangle, look at the triangles
    /// around that edge's or corner's vertices (a point inside a triangle is a local minimum of
    /// the distance over the surface: done). The triangles of the k nearest vertices can miss
    /// the closest one on an uneven mesh, and the match would then switch discretely as the
    /// query moves; the walk reaches it.
    fn walk(&mut self) {
        for _ in 0..64 {
            let Some((_, bf, bc)) = self.best else { return };
            if bc.iter().all(|&x| x > 0.0) {
                return;
            }
            let f = self.s.faces[bf];
            let mut improved = false;
            for c in 0..3 {
                if bc[c] > 0.0 {
                    improved |= self.around_vertex(f[c]);
                }
            }
            if !improved {
                return;
            }
        }
    }
}

impl Surface {
    /// Build from vertices (finite, mm), triangles (indices checked by the caller), unit vertex
    /// normals and boundary flags, all per vertex.
    pub fn new(points: Vec<Vec3>, faces: Vec<[usize; 3]>, normals: Vec<Vec3>, is_boundary: &[bool]) -> Result<Self, String> {
        let n = points.len();
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
        let tris = faces.iter().map(|f| Tri::new(points[f[0]], points[f[1]], points[f[2]])).collect();
        let tree = KdTree3::new(points)?;
        let boundary = is_boundary.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
        Ok(Self { tree, faces, tris, vf_offsets: count, vf_faces, normals, boundary })
    }

    /// The vertices.
    pub fn points(&self) -> &[Vec3] {
        self.tree.points()
    }

    /// Closest point of the surface to `q` among the triangles around its `k` nearest vertices
    /// and a walk from the best of them (ties: the lowest triangle id). `k` = 0: the nearest
    /// vertex itself (face `usize::MAX`), as a nearest-neighbour match.
    pub fn closest(&self, q: &Vec3, k: usize) -> SurfacePoint {
        self.closest_from(q, k, usize::MAX)
    }

    /// [`Surface::closest`] warm-started from triangle `start` (the query's triangle of the
    /// previous ICP round; `usize::MAX` = none): the walk starts there, and the k-nearest-vertex
    /// search runs only when the walk ends farther than [`WARM_TRUST`] mm from the query (far
    /// points have more local minima). A fit moves its template little between rounds, so this
    /// is a dozen triangle tests without the KD-tree query.
    pub fn closest_from(&self, q: &Vec3, k: usize, start: usize) -> SurfacePoint {
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
        let mut st = Search { s: self, q: *q, tested: [0; 96], n_tested: 0, best: None };
        let warm = start < self.faces.len();
        if warm {
            // the start triangle and every triangle touching it (an inside point of one triangle
            // alone is no local minimum: a neighbour across a concave edge can be closer)
            for &vi in &self.faces[start] {
                st.around_vertex(vi);
            }
        } else {
            st.around_nearest(k);
        }
        st.walk();
        if warm && st.best.map_or(true, |b| b.0 > WARM_TRUST * WARM_TRUST) {
            st.around_nearest(k);
            st.walk();
        }
        let pts = self.points();
        match st.best {
            Some((_, fi, bc)) => {
                let f = self.faces[fi];
                let p = add(add(scale(pts[f[0]], bc[0]), scale(pts[f[1]], bc[1])), scale(pts[f[2]], bc[2]));
                let d = dot(sub(*q, p), sub(*q, p));
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
                let (vi, d) = self.tree.nearest(q);
                SurfacePoint { face: usize::MAX, bary: [1.0, 0.0, 0.0], point: pts[vi], dist: d, normal: self.normals[vi], boundary: self.boundary[vi] }
            }
        }
    }

    /// [`Surface::closest_from`] of every query with its start triangle (`starts` empty = none).
    pub fn closest_all_from(&self, queries: &[Vec3], k: usize, starts: &[usize]) -> Vec<SurfacePoint> {
        queries
            .par_iter()
            .enumerate()
            .with_min_len(128)
            .map(|(i, q)| self.closest_from(q, k, starts.get(i).copied().unwrap_or(usize::MAX)))
            .collect()
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

