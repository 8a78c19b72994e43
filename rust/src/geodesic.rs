//! Geodesic distances on triangle meshes: Dijkstra on the edge graph and fast marching
//! (Kimmel & Sethian 1998) on the triangles.
//!
//! [`GeodesicSolver`] precomputes everything that depends only on the mesh (edge graph in CSR
//! form, vertex -> face CSR, face areas, and the FMM *update stencils* with their inverse Gram
//! matrices) and then serves many queries. Queries run on a reusable [`Workspace`] whose
//! per-vertex arrays are reset sparsely (only the vertices a propagation touched), so a query
//! truncated at `max_distance` costs time proportional to the area it reaches.
//!
//! ## The FMM update
//! A stencil is a triangle `(A, B, C)` used to update `C` once `A` and `B` are accepted. With
//! `X = [A-C, B-C]` and `G = XᵀX`, the local plane wave `T(x) = p + g·(x-C)`, `|g| = 1`, through
//! `T_A`, `T_B` gives the quadratic `(t - p1)ᵀ G⁻¹ (t - p1) = 1`; its larger root `p` is accepted
//! only if the wave comes from inside the triangle (`w = G⁻¹(t - p1) <= 0`: the characteristic
//! reaching `C` lies in the angle at `C`) and is causal (`p >= max(T_A, T_B)`); otherwise the
//! edge updates `T_A + |AC|`, `T_B + |BC|` (Dijkstra's) are used. Only the Gram matrix of the two
//! edge vectors is needed, so the stencil stores `G⁻¹` and `|AC|`.
//!
//! ## Obtuse triangles
//! At an obtuse angle of `C` the plane-wave update is often non-causal and the scheme degrades to
//! edge updates. As Kimmel & Sethian propose, we *unfold* the neighbouring triangles across the
//! edge opposite `C` into the plane of the triangle until an unfolded mesh vertex `D` lies in the
//! sub-cone of the angle at `C` that makes both `ACD` and `DCB` acute (at most [`MAX_UNFOLD`]
//! faces; none found -> no split). The two virtual acute triangles `(A, D, C)` and `(D, B, C)` are
//! added as extra stencils (the original one is kept: its checks make it harmless), with `|CD|`
//! the straight distance in the unfolded strip, a true path length on the surface.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};
use std::sync::Mutex;

use rayon::prelude::*;

use crate::vec3::{cross, dot, norm, sub};

/// Angles with a cosine below this (about 95 degrees) are split by unfolding. Angles just
/// above 90 degrees (common in quad-derived meshes) barely affect the updates and splitting
/// them only costs stencils.
pub const OBTUSE_SPLIT_COS: f64 = -0.087;

/// Faces unfolded at most when looking for the vertex that splits an obtuse angle.
pub const MAX_UNFOLD: usize = 16;

/// One FMM update: when `trigger` (the vertex whose list holds the stencil) is accepted, update
/// `target` from the edge `trigger -> target` and, if `other` is accepted too, from the triangle.
/// Geometry in the triangle's 2-D frame: target at the origin, trigger at `(len, 0)`, other at
/// `(bx, by)` with `by > 0` (`by = 0` marks a degenerate triangle: edge update only). 32 bytes,
/// so a vertex's stencils stay within a few cache lines.
#[derive(Clone, Copy, Debug)]
struct Stencil {
    target: u32,
    other: u32,
    /// |trigger - target| (for virtual stencils: the unfolded straight distance)
    len: f64,
    bx: f64,
    by: f64,
}

/// Propagation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Fast marching on the triangles (first order, obtuse angles split by unfolding).
    Fmm,
    /// Dijkstra on the edge graph (edge lengths; an upper bound of the geodesic distance).
    Dijkstra,
}

/// Heap entry: (bit pattern of the distance, vertex). Distances are non-negative, so their IEEE
/// bit patterns order like the values and the comparison is a plain integer one; ties are
/// broken by the vertex index (deterministic order). `Reverse` makes `BinaryHeap` a min-heap.
/// The heap uses lazy deletion: an improved vertex is pushed again, stale entries are skipped.
type HeapItem = Reverse<(u64, u32)>;

/// Label of a value from a plane wave through values of different sources: it is not the
/// distance to one point, so the point-source update must not use it.
const MIXED: u32 = u32::MAX;

const FAR: u8 = 0;
const TRIAL: u8 = 1;
const DONE: u8 = 2;

/// Per-vertex state of a propagation (16 bytes: one cache access per vertex).
#[derive(Clone, Copy)]
struct Node {
    dist: f64,
    /// index (into the sources) of the source the value comes from
    label: u32,
    state: u8,
    /// needed by a band propagation (neighbour of a vertex inside the radius)
    needed: bool,
}

const UNTOUCHED: Node = Node { dist: f64::INFINITY, label: 0, state: FAR, needed: false };

/// Per-query scratch: distances and states for all vertices, reset sparsely after each query.
pub struct Workspace {
    nodes: Vec<Node>,
    /// Vertices touched by the last propagation.
    pub touched: Vec<u32>,
    /// Vertices accepted (final) by the last propagation, in acceptance order.
    pub accepted: Vec<u32>,
    heap: BinaryHeap<HeapItem>,
}

impl Workspace {
    /// A workspace for a mesh of `n` vertices.
    pub fn new(n: usize) -> Self {
        Self { nodes: vec![UNTOUCHED; n], touched: Vec::new(), accepted: Vec::new(), heap: BinaryHeap::new() }
    }

    fn reset(&mut self) {
        for &v in &self.touched {
            self.nodes[v as usize] = UNTOUCHED;
        }
        self.touched.clear();
        self.accepted.clear();
        self.heap.clear();
    }

    /// Current distance of vertex `v` (final if accepted; `inf` when untouched).
    #[inline]
    pub fn dist(&self, v: usize) -> f64 {
        self.nodes[v].dist
    }

    /// True when vertex `v` was accepted by the last propagation (its distance is final).
    #[inline]
    pub fn is_accepted(&self, v: usize) -> bool {
        self.nodes[v].state == DONE
    }

    #[inline]
    fn relax(&mut self, v: u32, d: f64, label: u32) {
        let node = &mut self.nodes[v as usize];
        if node.state == DONE {
            return;
        }
        if node.state == FAR {
            node.state = TRIAL;
            self.touched.push(v);
        }
        if d < node.dist {
            node.dist = d;
            node.label = label;
            self.heap.push(Reverse((d.to_bits(), v)));
        }
    }
}

/// Precomputed per-mesh data for geodesic queries.
pub struct GeodesicSolver {
    n: usize,
    faces: Vec<[u32; 3]>,
    face_area: Vec<f64>,
    nbr_off: Vec<u32>,
    nbr: Vec<u32>,
    nbr_len: Vec<f64>,
    st_off: Vec<u32>,
    st: Vec<Stencil>,
    vf_off: Vec<u32>,
    vf: Vec<u32>,
    owned_off: Vec<u32>,
    max_edge: f64,
    n_split: usize,
    old_of_new: Vec<u32>,
    new_of_old: Vec<u32>,
    pool: Mutex<Vec<Workspace>>,
}

/// Build a CSR (offsets, values) from (key, value) pairs with keys < n.
fn csr<T: Copy>(n: usize, pairs: &[(u32, T)]) -> (Vec<u32>, Vec<T>) {
    let mut off = vec![0u32; n + 1];
    for &(k, _) in pairs {
        off[k as usize + 1] += 1;
    }
    for i in 0..n {
        off[i + 1] += off[i];
    }
    let mut pos: Vec<u32> = off[..n].to_vec();
    let mut vals: Vec<Option<T>> = vec![None; pairs.len()];
    for &(k, v) in pairs {
        vals[pos[k as usize] as usize] = Some(v);
        pos[k as usize] += 1;
    }
    (off, vals.into_iter().map(|x| x.unwrap()).collect())
}

/// Stencil for target C from the Gram matrix of e1 = A - C (trigger A) and e2 = B - C.
fn make_stencil(target: u32, other: u32, g11: f64, g22: f64, g12: f64) -> Stencil {
    let len = g11.sqrt();
    let bx = g12 / len;
    let by2 = g22 - bx * bx;
    let by = if by2 > 1e-12 * g22 && len > 0.0 { by2.sqrt() } else { 0.0 };
    Stencil { target, other, len, bx, by }
}

/// Point-source update of the target of `s` (Novotni & Klein): unfold the virtual source `S`
/// with `|S - A| = ta`, `|S - B| = tb` beyond the edge AB; if the straight ray from `S` to the
/// target crosses AB (S in the angle at the target) the distance is `|S - C|`. Exact on
/// developable surfaces. Returns `inf` when the ray misses the triangle or the result would not
/// be causal (the wave reaches the target through another triangle), NaN when the circles do
/// not meet (the values do not fit one point source: the caller tries a plane wave).
#[inline]
fn source_update(s: &Stencil, ta: f64, tb: f64) -> f64 {
    let (ax, bx, by) = (s.len, s.bx, s.by);
    if by <= 0.0 {
        return f64::INFINITY;
    }
    // S = A + alpha e + beta perp(e), e = B - A, perp(e) = (-ey, ex) points to the target's
    // side negated below; |S - A| = ta, |S - B| = tb
    let (ex, ey) = (bx - ax, by);
    let l2 = ex * ex + ey * ey;
    let inv_l2 = 1.0 / l2;
    let alpha = 0.5 * (ta * ta - tb * tb + l2) * inv_l2;
    let beta2 = ta * ta * inv_l2 - alpha * alpha;
    if beta2 < 0.0 {
        return f64::NAN; // the values are not those of one point source: try a plane wave
    }
    // perp(e) = (-ey, ex); the origin lies on the side of sign(perp(e) . (0 - A)) = sign(ey * ax) > 0,
    // so the virtual source goes the other way: S = A + alpha e - beta perp(e)
    let beta = beta2.sqrt();
    let sx = ax + alpha * ex + beta * ey;
    let sy = alpha * ey - beta * ex;
    // S inside the angle at the target: between directions (ax, 0) and (bx, by), by > 0
    let tol = 1e-12 * (sx.abs() + sy.abs());
    if sy < -tol || sx * by - sy * bx < -tol {
        return f64::INFINITY;
    }
    let p = (sx * sx + sy * sy).sqrt();
    if p >= ta && p >= tb {
        p
    } else {
        f64::INFINITY
    }
}

/// Plane-wave update of the target of `s` from the trigger's value `ta` and the other's `tb`.
/// Returns `inf` when the wave does not come from inside the triangle or is not causal.
#[inline]
fn triangle_update(s: &Stencil, ta: f64, tb: f64) -> f64 {
    let (ax, bx, by) = (s.len, s.bx, s.by);
    if by <= 0.0 {
        return f64::INFINITY;
    }
    // inverse Gram matrix of (ax, 0), (bx, by): det = (ax by)^2
    let inv_det = 1.0 / (ax * ax * by * by);
    let (q11, q12, q22) = ((bx * bx + by * by) * inv_det, -ax * bx * inv_det, ax * ax * inv_det);
    let sq = q11 + 2.0 * q12 + q22;
    let m = (q11 + q12) * ta + (q12 + q22) * tb;
    let q = q11 * ta * ta + 2.0 * q12 * ta * tb + q22 * tb * tb;
    let disc = m * m - sq * (q - 1.0);
    if disc < 0.0 || sq <= 0.0 {
        return f64::INFINITY;
    }
    let p = (m + disc.sqrt()) / sq;
    let (da, db) = (ta - p, tb - p);
    let w1 = q11 * da + q12 * db;
    let w2 = q12 * da + q22 * db;
    if w1 <= 0.0 && w2 <= 0.0 && p >= ta && p >= tb {
        p
    } else {
        f64::INFINITY
    }
}

/// Unfold the strip of faces beyond the edge (a, b) opposite the obtuse corner c of face `f`,
/// looking for a vertex in the sub-cone that splits the angle at c into two acute angles.
/// Returns (d, 2-D position of d with c at the origin and a on the +x axis, 2-D position of b).
fn find_split_vertex(
    verts: &[[f64; 3]],
    faces: &[[u32; 3]],
    edge_faces: &HashMap<(u32, u32), [u32; 2]>,
    f: usize,
    ci: usize,
) -> Option<(u32, [f64; 2], [f64; 2])> {
    let c = faces[f][ci];
    let a = faces[f][(ci + 1) % 3];
    let b = faces[f][(ci + 2) % 3];
    let (pc, pa, pb) = (&verts[c as usize], &verts[a as usize], &verts[b as usize]);
    let ca = sub(*pa, *pc);
    let cb = sub(*pb, *pc);
    let la = norm(ca);
    let bx = dot(cb, ca) / la;
    let by = (dot(cb, cb) - bx * bx).max(0.0).sqrt();
    let a2 = [la, 0.0];
    let b2 = [bx, by];
    // The acute sub-cone: angle(d) in (theta - 90deg, 90deg), theta = angle of b (> 90deg).
    let theta = b2[1].atan2(b2[0]);
    let (lo, hi) = (theta - std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2);
    let (mut p, mut q) = (a, b); // p on the a-side, q on the b-side
    let (mut p2, mut q2) = (a2, b2);
    let mut prev_face = f as u32;
    let mut prev2 = [0.0f64, 0.0f64]; // third vertex of the face we came from (c at first)
    for _ in 0..MAX_UNFOLD {
        let key = if p < q { (p, q) } else { (q, p) };
        let adj = edge_faces.get(&key)?;
        let g = if adj[0] == prev_face { adj[1] } else { adj[0] };
        if g == u32::MAX || g == prev_face {
            return None;
        }
        let gf = faces[g as usize];
        let d = *gf.iter().find(|&&x| x != p && x != q)?;
        let pd = &verts[d as usize];
        let lpd2 = {
            let e = sub(*pd, verts[p as usize]);
            dot(e, e)
        };
        let lqd2 = {
            let e = sub(*pd, verts[q as usize]);
            dot(e, e)
        };
        let e = [q2[0] - p2[0], q2[1] - p2[1]];
        let l = (e[0] * e[0] + e[1] * e[1]).sqrt();
        if l <= 0.0 {
            return None;
        }
        let along = (lpd2 - lqd2 + l * l) / (2.0 * l);
        let h = (lpd2 - along * along).max(0.0).sqrt();
        let u = [e[0] / l, e[1] / l];
        let nrm = [-u[1], u[0]];
        // put d on the side of line pq opposite the previous third vertex
        let side_prev = (prev2[0] - p2[0]) * nrm[0] + (prev2[1] - p2[1]) * nrm[1];
        let sgn = if side_prev > 0.0 { -1.0 } else { 1.0 };
        let d2 = [
            p2[0] + along * u[0] + sgn * h * nrm[0],
            p2[1] + along * u[1] + sgn * h * nrm[1],
        ];
        let phi = d2[1].atan2(d2[0]);
        if phi > lo && phi < hi {
            return Some((d, d2, b2));
        }
        // continue through the edge of g that the acute sub-cone crosses
        if phi <= lo {
            // d lies on the a-side of the sub-cone: it crosses edge (d, q)
            prev2 = p2;
            p = d;
            p2 = d2;
        } else {
            prev2 = q2;
            q = d;
            q2 = d2;
        }
        prev_face = g;
    }
    None
}

/// Vertex order along a Morton curve of a 2^10 grid over the bounding box (old index per new).
fn morton_order(verts: &[[f64; 3]]) -> Vec<u32> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in verts {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let ext = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max).max(1e-300);
    let spread = |x: u64| {
        // interleave the low 10 bits with two zero bits each
        let mut r = 0u64;
        for b in 0..10 {
            r |= ((x >> b) & 1) << (3 * b);
        }
        r
    };
    let mut keyed: Vec<(u64, u32)> = verts
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = |k: usize| (((p[k] - lo[k]) / ext * 1023.0) as u64).min(1023);
            (spread(q(0)) | (spread(q(1)) << 1) | (spread(q(2)) << 2), i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|x| x.1).collect()
}

impl GeodesicSolver {
    /// Precompute the solver for vertices `verts` (N) and triangles `faces` (M, indices < N).
    /// Faces with repeated indices are ignored; zero-area faces only contribute their edges.
    pub fn new(verts: &[[f64; 3]], faces: &[[u32; 3]]) -> Result<Self, String> {
        let n = verts.len();
        if n >= u32::MAX as usize {
            return Err("too many vertices".into());
        }
        for (i, f) in faces.iter().enumerate() {
            if f.iter().any(|&x| x as usize >= n) {
                return Err(format!("face {i} has a vertex index out of range [0, {n})"));
            }
        }
        // Internal vertex order: along a Morton (Z-order) curve, so that a propagation touches
        // nearby memory (per-vertex state and stencils); faces sorted by their first vertex.
        let old_of_new = morton_order(verts);
        let mut new_of_old = vec![0u32; n];
        for (i, &o) in old_of_new.iter().enumerate() {
            new_of_old[o as usize] = i as u32;
        }
        let verts: Vec<[f64; 3]> = old_of_new.iter().map(|&o| verts[o as usize]).collect();
        let verts = &verts[..];
        let mut faces: Vec<[u32; 3]> = faces
            .iter()
            .map(|f| [new_of_old[f[0] as usize], new_of_old[f[1] as usize], new_of_old[f[2] as usize]])
            .filter(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2])
            .collect();
        faces.sort_by_key(|f| *f.iter().min().unwrap());
        let face_area: Vec<f64> = faces
            .iter()
            .map(|f| {
                let e1 = sub(verts[f[1] as usize], verts[f[0] as usize]);
                let e2 = sub(verts[f[2] as usize], verts[f[0] as usize]);
                let c = cross(e1, e2);
                0.5 * norm(c)
            })
            .collect();

        // edge graph and edge -> faces
        let mut edge_faces: HashMap<(u32, u32), [u32; 2]> = HashMap::with_capacity(faces.len() * 2);
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                let key = if a < b { (a, b) } else { (b, a) };
                let e = edge_faces.entry(key).or_insert([u32::MAX, u32::MAX]);
                if e[0] == u32::MAX {
                    e[0] = fi as u32;
                } else if e[1] == u32::MAX {
                    e[1] = fi as u32;
                }
            }
        }
        let mut keys: Vec<(u32, u32)> = edge_faces.keys().copied().collect();
        keys.sort_unstable();
        let mut pairs: Vec<(u32, (u32, f64))> = Vec::with_capacity(keys.len() * 2);
        let mut max_edge: f64 = 0.0;
        for &(a, b) in &keys {
            let e = sub(verts[a as usize], verts[b as usize]);
            let l = norm(e);
            max_edge = max_edge.max(l);
            pairs.push((a, (b, l)));
            pairs.push((b, (a, l)));
        }
        let (nbr_off, nl) = csr(n, &pairs);
        let nbr: Vec<u32> = nl.iter().map(|x| x.0).collect();
        let nbr_len: Vec<f64> = nl.iter().map(|x| x.1).collect();

        // stencils, keyed by trigger vertex
        let per_face: Vec<Vec<(u32, Stencil)>> = faces
            .par_iter()
            .enumerate()
            .map(|(fi, f)| {
                let mut out = Vec::with_capacity(6);
                for ci in 0..3 {
                    let c = f[ci];
                    let a = f[(ci + 1) % 3];
                    let b = f[(ci + 2) % 3];
                    let pc = &verts[c as usize];
                    let ea = sub(verts[a as usize], *pc);
                    let eb = sub(verts[b as usize], *pc);
                    let (gaa, gbb, gab) = (dot(ea, ea), dot(eb, eb), dot(ea, eb));
                    out.push((a, make_stencil(c, b, gaa, gbb, gab)));
                    out.push((b, make_stencil(c, a, gbb, gaa, gab)));
                    if gab < OBTUSE_SPLIT_COS * (gaa * gbb).sqrt() && face_area[fi] > 0.0 {
                        if let Some((d, d2, b2)) = find_split_vertex(verts, &faces, &edge_faces, fi, ci) {
                            let la = gaa.sqrt();
                            let dd = d2[0] * d2[0] + d2[1] * d2[1];
                            // virtual triangle (a, d, c): vectors a2 = (la, 0), d2
                            let gad = la * d2[0];
                            out.push((a, make_stencil(c, d, gaa, dd, gad)));
                            out.push((d, make_stencil(c, a, dd, gaa, gad)));
                            // virtual triangle (d, b, c)
                            let gdb = d2[0] * b2[0] + d2[1] * b2[1];
                            out.push((d, make_stencil(c, b, dd, gbb, gdb)));
                            out.push((b, make_stencil(c, d, gbb, dd, gdb)));
                        }
                    }
                }
                out
            })
            .collect();
        let n_split = per_face.iter().map(|v| (v.len() - 6) / 4).sum();
        let flat: Vec<(u32, Stencil)> = per_face.into_iter().flatten().collect();
        let (st_off, mut st) = csr(n, &flat);
        // group each trigger's stencils by target: one relaxation per (trigger, target)
        for v in 0..n {
            st[st_off[v] as usize..st_off[v + 1] as usize].sort_by_key(|x| x.target);
        }

        let vfp: Vec<(u32, u32)> = faces
            .iter()
            .enumerate()
            .flat_map(|(fi, f)| f.iter().map(move |&v| (v, fi as u32)))
            .collect();
        let (vf_off, vf) = csr(n, &vfp);
        // faces are sorted by their lowest vertex: owned_off[v]..owned_off[v+1] are v's
        let mut owned_off = vec![0u32; n + 1];
        for f in &faces {
            owned_off[*f.iter().min().unwrap() as usize + 1] += 1;
        }
        for i in 0..n {
            owned_off[i + 1] += owned_off[i];
        }

        Ok(Self {
            n,
            faces,
            face_area,
            nbr_off,
            nbr,
            nbr_len,
            st_off,
            st,
            vf_off,
            vf,
            owned_off,
            max_edge,
            n_split,
            old_of_new,
            new_of_old,
            pool: Mutex::new(Vec::new()),
        })
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n
    }
    /// Internal index of (caller's) vertex `v`. Everything below the public query methods
    /// (`propagate*`, `faces`, `vertex_faces`, workspace contents) uses internal indices.
    #[inline]
    pub fn internal(&self, v: u32) -> u32 {
        self.new_of_old[v as usize]
    }
    /// Caller's index of internal vertex `v`.
    #[inline]
    pub fn external(&self, v: u32) -> u32 {
        self.old_of_new[v as usize]
    }
    /// The (non-degenerate-index) faces used, in internal indices.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
    /// Area of each face in `faces()`.
    pub fn face_areas(&self) -> &[f64] {
        &self.face_area
    }
    /// Faces incident to vertex `v` (indices into `faces()`).
    pub fn vertex_faces(&self, v: usize) -> &[u32] {
        &self.vf[self.vf_off[v] as usize..self.vf_off[v + 1] as usize]
    }
    /// Faces whose lowest (internal) vertex index is `v`, as a range into `faces()`.
    pub fn owned_faces(&self, v: usize) -> std::ops::Range<usize> {
        self.owned_off[v] as usize..self.owned_off[v + 1] as usize
    }
    /// Longest edge length.
    pub fn max_edge(&self) -> f64 {
        self.max_edge
    }
    /// Number of obtuse angles split by unfolding.
    pub fn n_obtuse_split(&self) -> usize {
        self.n_split
    }

    /// Run `f` with a workspace taken from (and returned to) the solver's pool.
    pub fn with_workspace<R>(&self, f: impl FnOnce(&mut Workspace) -> R) -> R {
        let ws = self.pool.lock().unwrap().pop();
        let mut ws = ws.unwrap_or_else(|| Workspace::new(self.n));
        let r = f(&mut ws);
        ws.reset();
        self.pool.lock().unwrap().push(ws);
        r
    }

    /// Propagate from `sources` (distance 0) into `ws`, accepting vertices in order of distance
    /// until the next one would exceed `stop`. Afterwards `ws.is_accepted(v)` marks final values
    /// (exactly the vertices with distance <= stop); other touched vertices hold upper bounds.
    pub fn propagate(&self, ws: &mut Workspace, sources: &[u32], stop: f64, method: Method) {
        self.run(ws, sources, method, |_, _, _| stop);
    }

    /// The propagation loop; `stop(v, d)` is called after accepting `v` at distance `d` and
    /// returns the current stopping distance (the loop ends before accepting a vertex beyond it).
    #[inline]
    fn run(
        &self,
        ws: &mut Workspace,
        sources: &[u32],
        method: Method,
        mut stop_after: impl FnMut(&mut Workspace, u32, f64) -> f64,
    ) {
        ws.reset();
        let mut stop = f64::INFINITY;
        for (k, &s) in sources.iter().enumerate() {
            ws.relax(s, 0.0, k as u32);
        }
        while let Some(Reverse((bits, v))) = ws.heap.pop() {
            let d = f64::from_bits(bits);
            let vi = v as usize;
            if ws.nodes[vi].state == DONE || d > ws.nodes[vi].dist {
                continue; // stale entry
            }
            if d > stop {
                break;
            }
            ws.nodes[vi].state = DONE;
            ws.accepted.push(v);
            stop = stop_after(ws, v, d);
            match method {
                Method::Dijkstra => {
                    let (s, e) = (self.nbr_off[vi] as usize, self.nbr_off[vi + 1] as usize);
                    for j in s..e {
                        ws.relax(self.nbr[j], d + self.nbr_len[j], ws.nodes[vi].label);
                    }
                }
                Method::Fmm => {
                    let lab = ws.nodes[vi].label;
                    let (s, e) = (self.st_off[vi] as usize, self.st_off[vi + 1] as usize);
                    let stl = &self.st[s..e];
                    let mut i = 0;
                    while i < stl.len() {
                        let t = stl[i].target;
                        let mut j = i;
                        if ws.nodes[t as usize].state == DONE {
                            while j < stl.len() && stl[j].target == t {
                                j += 1;
                            }
                            i = j;
                            continue;
                        }
                        let mut cand = f64::INFINITY;
                        let mut cand_lab = lab;
                        while j < stl.len() && stl[j].target == t {
                            let st = &stl[j];
                            j += 1;
                            if d + st.len < cand {
                                cand = d + st.len;
                                cand_lab = lab;
                            }
                            let on = ws.nodes[st.other as usize];
                            if on.state == DONE {
                                let to = on.dist;
                                // the point-source model needs both values from one point source
                                let same = on.label == lab && lab != MIXED;
                                let p = if same { source_update(st, d, to) } else { f64::NAN };
                                let p = if p.is_nan() { triangle_update(st, d, to) } else { p };
                                if p < cand {
                                    cand = p;
                                    cand_lab = if on.label == lab { lab } else { MIXED };
                                }
                            }
                        }
                        ws.relax(t, cand, cand_lab);
                        i = j;
                    }
                }
            }
        }
    }

    /// Like [`propagate`](Self::propagate) with `stop = radius`, but continues until every
    /// vertex adjacent to a vertex with distance `< radius` is accepted too (so every triangle
    /// meeting the disk has final values at its corners). The neighbours of each vertex
    /// accepted inside the radius are marked as needed and counted; the propagation stops at
    /// the first vertex beyond `radius` once no needed vertex is pending. The pop order is that
    /// of a full propagation, so the accepted values are identical to it.
    pub fn propagate_band(&self, ws: &mut Workspace, sources: &[u32], radius: f64, method: Method) {
        let mut pending = 0usize;
        self.run(ws, sources, method, |ws, v, d| {
            let vi = v as usize;
            if ws.nodes[vi].needed {
                pending -= 1;
            }
            if d < radius {
                for j in self.nbr_off[vi] as usize..self.nbr_off[vi + 1] as usize {
                    let x = self.nbr[j];
                    let nx = &mut ws.nodes[x as usize];
                    if nx.state != DONE && !nx.needed {
                        nx.needed = true;
                        pending += 1;
                        if nx.state == FAR {
                            nx.state = TRIAL;
                            ws.touched.push(x);
                        }
                    }
                }
            }
            if pending > 0 {
                f64::INFINITY
            } else {
                radius
            }
        });
    }

    /// Distances (N) to the nearest of `sources`; `inf` beyond `max_distance` or unreachable.
    pub fn distances(&self, sources: &[u32], max_distance: f64, method: Method) -> Vec<f64> {
        let mut out = vec![f64::INFINITY; self.n];
        let src: Vec<u32> = sources.iter().map(|&s| self.internal(s)).collect();
        self.with_workspace(|ws| {
            self.propagate(ws, &src, max_distance, method);
            for &v in &ws.accepted {
                out[self.external(v) as usize] = ws.dist(v as usize);
            }
        });
        out
    }

    /// One propagation per source, in parallel; row-major (S, N).
    pub fn distance_matrix(&self, sources: &[u32], max_distance: f64, method: Method) -> Vec<f64> {
        let n = self.n;
        let mut out = vec![f64::INFINITY; sources.len() * n];
        if n == 0 {
            return out;
        }
        out.par_chunks_mut(n).zip(sources.par_iter()).for_each(|(row, &s)| {
            self.with_workspace(|ws| {
                self.propagate(ws, &[self.internal(s)], max_distance, method);
                for &v in &ws.accepted {
                    row[self.external(v) as usize] = ws.dist(v as usize);
                }
            })
        });
        out
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Regular grid of (nx+1) x (ny+1) vertices with spacing h, each square split by a diagonal.
    pub fn grid(nx: usize, ny: usize, h: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let (v, f) = crate::fixtures::grid(nx + 1, ny + 1, |i, j| [i as f64 * h, j as f64 * h, 0.0]);
        (v, crate::fixtures::faces_u32(f))
    }

    /// On a plane the FMM distance from a vertex is the Euclidean one to 1e-9 relative.
    #[test]
    fn point_source_on_plane_is_exact() {
        let (v, f) = grid(40, 40, 0.5);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let c = 20 * 41 + 20;
        let d = s.distances(&[c as u32], f64::INFINITY, Method::Fmm);
        for (i, p) in v.iter().enumerate() {
            let e = ((p[0] - 10.0).powi(2) + (p[1] - 10.0).powi(2)).sqrt();
            assert!((d[i] - e).abs() <= 1e-9 * e, "{i}: {} vs {e}", d[i]);
        }
    }

    #[test]
    fn line_of_sources_gives_distance_to_line() {
        let (v, f) = grid(20, 20, 0.5);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let src: Vec<u32> = (0..=20).map(|j| (j * 21) as u32).collect(); // x = 0 column
        let d = s.distances(&src, f64::INFINITY, Method::Fmm);
        for (i, p) in v.iter().enumerate() {
            assert!((d[i] - p[0]).abs() < 1e-12, "{} vs {}", d[i], p[0]);
        }
    }

    #[test]
    fn dijkstra_on_path() {
        let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [5.0, 5.0, 5.0]];
        let f = vec![[0, 1, 2]];
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let d = s.distances(&[0], f64::INFINITY, Method::Dijkstra);
        assert_eq!(d[0], 0.0);
        assert_eq!(d[1], 1.0);
        assert!((d[2] - 2f64.sqrt()).abs() < 1e-15);
        assert!(d[3].is_infinite());
    }

    #[test]
    fn truncation_equals_full_result() {
        let (v, f) = grid(30, 30, 0.3);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let full = s.distances(&[100, 700], f64::INFINITY, Method::Fmm);
        let part = s.distances(&[100, 700], 2.0, Method::Fmm);
        for i in 0..v.len() {
            if full[i] <= 2.0 {
                assert_eq!(full[i], part[i]);
            } else {
                assert!(part[i].is_infinite());
            }
        }
    }

    #[test]
    fn obtuse_triangles_are_split() {
        // a strip of very obtuse triangles: the split must find vertices and FMM stay accurate
        // a lattice of flat triangles with ~147 degree angles
        let (nx, ny) = (30usize, 30usize);
        let mut v = Vec::new();
        for j in 0..=ny {
            for i in 0..=nx {
                v.push([i as f64 + 0.5 * (j % 2) as f64, 0.15 * j as f64, 0.0]);
            }
        }
        let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        let mut f = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                if j % 2 == 0 {
                    f.push([id(i, j), id(i + 1, j), id(i, j + 1)]);
                    f.push([id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
                } else {
                    f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
                    f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                }
            }
        }
        let s = GeodesicSolver::new(&v, &f).unwrap();
        assert!(s.n_obtuse_split() > 0);
        let c = id(15, 16) as usize;
        let d = s.distances(&[c as u32], f64::INFINITY, Method::Fmm);
        let mut worst: f64 = 0.0;
        for (i, p) in v.iter().enumerate() {
            let e = ((p[0] - v[c][0]).powi(2) + (p[1] - v[c][1]).powi(2)).sqrt();
            if i != c {
                worst = worst.max((d[i] - e).abs() / e);
            }
        }
        assert!(worst < 1e-9, "worst rel err {worst}");
    }

    #[test]
    fn matrix_matches_rows() {
        let (v, f) = grid(10, 10, 1.0);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let m = s.distance_matrix(&[0, 5, 60], f64::INFINITY, Method::Fmm);
        for (r, &src) in [0u32, 5, 60].iter().enumerate() {
            let d = s.distances(&[src], f64::INFINITY, Method::Fmm);
            assert_eq!(&m[r * v.len()..(r + 1) * v.len()], &d[..]);
        }
    }

    #[test]
    fn bad_index_is_an_error() {
        let v = vec![[0.0; 3]; 3];
        assert!(GeodesicSolver::new(&v, &[[0, 1, 3]]).is_err());
    }
}
