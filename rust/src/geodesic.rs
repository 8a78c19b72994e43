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

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};
use std::sync::Mutex;

use rayon::prelude::*;

/// Faces unfolded at most when looking for the vertex that splits an obtuse angle.
pub const MAX_UNFOLD: usize = 16;

/// One FMM update: when `trigger` (the vertex whose list holds the stencil) is accepted, update
/// `target` from the edge `trigger -> target` and, if `other` is accepted too, from the triangle.
#[derive(Clone, Copy, Debug)]
struct Stencil {
    target: u32,
    other: u32,
    /// |trigger - target| (for virtual stencils: the unfolded straight distance)
    len: f64,
    /// the other vertex in the 2-D frame with the target at the origin and the trigger at (len, 0)
    bx: f64,
    by: f64,
    /// inverse Gram matrix of [trigger - target, other - target]; q11 = NaN for degenerate
    q11: f64,
    q12: f64,
    q22: f64,
}

/// Propagation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Fast marching on the triangles (first order, obtuse angles split by unfolding).
    Fmm,
    /// Dijkstra on the edge graph (edge lengths; an upper bound of the geodesic distance).
    Dijkstra,
}

#[derive(Clone, Copy, PartialEq)]
struct HeapItem(f64, u32);
impl Eq for HeapItem {}
impl PartialOrd for HeapItem {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for HeapItem {
    // min-heap on the distance, ties broken by the vertex index (deterministic order)
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then_with(|| other.1.cmp(&self.1))
    }
}

const FAR: u8 = 0;
const TRIAL: u8 = 1;
const DONE: u8 = 2;

/// Per-query scratch: distances and states for all vertices, reset sparsely after each query.
pub struct Workspace {
    /// Tentative / final distance per vertex (`inf` when untouched).
    pub dist: Vec<f64>,
    /// Index (into the sources) of the source each vertex's value comes from.
    label: Vec<u32>,
    state: Vec<u8>,
    /// Vertices touched by the last propagation.
    pub touched: Vec<u32>,
    /// Vertices accepted (final) by the last propagation, in acceptance order.
    pub accepted: Vec<u32>,
    heap: BinaryHeap<HeapItem>,
}

impl Workspace {
    /// A workspace for a mesh of `n` vertices.
    pub fn new(n: usize) -> Self {
        Self {
            dist: vec![f64::INFINITY; n],
            label: vec![0; n],
            state: vec![FAR; n],
            touched: Vec::new(),
            accepted: Vec::new(),
            heap: BinaryHeap::new(),
        }
    }

    fn reset(&mut self) {
        for &v in &self.touched {
            self.dist[v as usize] = f64::INFINITY;
            self.state[v as usize] = FAR;
        }
        self.touched.clear();
        self.accepted.clear();
        self.heap.clear();
    }

    /// True when vertex `v` was accepted by the last propagation (its distance is final).
    #[inline]
    pub fn is_accepted(&self, v: usize) -> bool {
        self.state[v] == DONE
    }

    #[inline]
    fn relax(&mut self, v: u32, d: f64, label: u32) {
        let s = self.state[v as usize];
        if s == DONE {
            return;
        }
        if s == FAR {
            self.state[v as usize] = TRIAL;
            self.touched.push(v);
        }
        if d < self.dist[v as usize] {
            self.dist[v as usize] = d;
            self.label[v as usize] = label;
            self.heap.push(HeapItem(d, v));
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
    max_edge: f64,
    n_split: usize,
    pool: Mutex<Vec<Workspace>>,
}

#[inline]
fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
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

/// Stencil for target C from 2-D/3-D edge vectors e1 = A - C (trigger A), e2 = B - C.
fn make_stencil(target: u32, other: u32, g11: f64, g22: f64, g12: f64) -> Stencil {
    let det = g11 * g22 - g12 * g12;
    let len = g11.sqrt();
    if !(det > 1e-12 * g11 * g22) {
        return Stencil { target, other, len, bx: 0.0, by: 0.0, q11: f64::NAN, q12: 0.0, q22: 0.0 };
    }
    let bx = g12 / len;
    let by = (g22 - bx * bx).max(0.0).sqrt();
    Stencil { target, other, len, bx, by, q11: g22 / det, q12: -g12 / det, q22: g11 / det }
}

/// Point-source update of the target of `s` (Novotni & Klein): unfold the virtual source `S`
/// with `|S - A| = ta`, `|S - B| = tb` beyond the edge AB; if the straight ray from `S` to the
/// target crosses AB (S in the angle at the target) the distance is `|S - C|`. Exact on
/// developable surfaces. Returns `inf` when the circles do not meet, the ray misses the
/// triangle, or the result would not be causal.
#[inline]
fn source_update(s: &Stencil, ta: f64, tb: f64) -> f64 {
    if s.q11.is_nan() {
        return f64::INFINITY;
    }
    let (ax, bx, by) = (s.len, s.bx, s.by);
    let (ex, ey) = (bx - ax, by);
    let l2 = ex * ex + ey * ey;
    let l = l2.sqrt();
    let along = (ta * ta - tb * tb + l2) / (2.0 * l);
    let h2 = ta * ta - along * along;
    if h2 < 0.0 {
        return f64::INFINITY;
    }
    let h = h2.sqrt();
    let (ux, uy) = (ex / l, ey / l);
    let (nx, ny) = (-uy, ux);
    // the target (origin) is on the side sign(n . (0 - A)) of line AB; S goes to the other side
    let side = -(nx * ax);
    let sg = if side > 0.0 { -1.0 } else { 1.0 };
    let sx = ax + along * ux + sg * h * nx;
    let sy = along * uy + sg * h * ny;
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
    let (q11, q12, q22) = (s.q11, s.q12, s.q22);
    if q11.is_nan() {
        return f64::INFINITY;
    }
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
    let ca = sub(pa, pc);
    let cb = sub(pb, pc);
    let la = dot(&ca, &ca).sqrt();
    let bx = dot(&cb, &ca) / la;
    let by = (dot(&cb, &cb) - bx * bx).max(0.0).sqrt();
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
            let e = sub(pd, &verts[p as usize]);
            dot(&e, &e)
        };
        let lqd2 = {
            let e = sub(pd, &verts[q as usize]);
            dot(&e, &e)
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
        let faces: Vec<[u32; 3]> = faces
            .iter()
            .copied()
            .filter(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2])
            .collect();
        let face_area: Vec<f64> = faces
            .iter()
            .map(|f| {
                let e1 = sub(&verts[f[1] as usize], &verts[f[0] as usize]);
                let e2 = sub(&verts[f[2] as usize], &verts[f[0] as usize]);
                let c = cross(&e1, &e2);
                0.5 * dot(&c, &c).sqrt()
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
            let e = sub(&verts[a as usize], &verts[b as usize]);
            let l = dot(&e, &e).sqrt();
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
                    let ea = sub(&verts[a as usize], pc);
                    let eb = sub(&verts[b as usize], pc);
                    let (gaa, gbb, gab) = (dot(&ea, &ea), dot(&eb, &eb), dot(&ea, &eb));
                    out.push((a, make_stencil(c, b, gaa, gbb, gab)));
                    out.push((b, make_stencil(c, a, gbb, gaa, gab)));
                    if gab < 0.0 && face_area[fi] > 0.0 {
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
        let (st_off, st) = csr(n, &flat);

        let vfp: Vec<(u32, u32)> = faces
            .iter()
            .enumerate()
            .flat_map(|(fi, f)| f.iter().map(move |&v| (v, fi as u32)))
            .collect();
        let (vf_off, vf) = csr(n, &vfp);

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
            max_edge,
            n_split,
            pool: Mutex::new(Vec::new()),
        })
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n
    }
    /// The (non-degenerate-index) faces used.
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
        ws.reset();
        for (k, &s) in sources.iter().enumerate() {
            ws.relax(s, 0.0, k as u32);
        }
        while let Some(HeapItem(d, v)) = ws.heap.pop() {
            let vi = v as usize;
            if ws.state[vi] == DONE || d > ws.dist[vi] {
                continue; // stale entry
            }
            if d > stop {
                break;
            }
            ws.state[vi] = DONE;
            ws.accepted.push(v);
            match method {
                Method::Dijkstra => {
                    let (s, e) = (self.nbr_off[vi] as usize, self.nbr_off[vi + 1] as usize);
                    for j in s..e {
                        ws.relax(self.nbr[j], d + self.nbr_len[j], ws.label[vi]);
                    }
                }
                Method::Fmm => {
                    let lab = ws.label[vi];
                    let (s, e) = (self.st_off[vi] as usize, self.st_off[vi + 1] as usize);
                    for st in &self.st[s..e] {
                        let t = st.target as usize;
                        if ws.state[t] == DONE {
                            continue;
                        }
                        let mut cand = d + st.len;
                        let o = st.other as usize;
                        if ws.state[o] == DONE {
                            let to = ws.dist[o];
                            // the point-source model needs both values from the same source
                            let p = if ws.label[o] == lab { source_update(st, d, to) } else { f64::INFINITY };
                            let p = if p.is_finite() { p } else { triangle_update(st, d, to) };
                            cand = cand.min(p);
                        }
                        ws.relax(st.target, cand, lab);
                    }
                }
            }
        }
    }

    /// Distances (N) to the nearest of `sources`; `inf` beyond `max_distance` or unreachable.
    pub fn distances(&self, sources: &[u32], max_distance: f64, method: Method) -> Vec<f64> {
        let mut out = vec![f64::INFINITY; self.n];
        self.with_workspace(|ws| {
            self.propagate(ws, sources, max_distance, method);
            for &v in &ws.accepted {
                out[v as usize] = ws.dist[v as usize];
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
                self.propagate(ws, &[s], max_distance, method);
                for &v in &ws.accepted {
                    row[v as usize] = ws.dist[v as usize];
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
        let mut v = Vec::new();
        for j in 0..=ny {
            for i in 0..=nx {
                v.push([i as f64 * h, j as f64 * h, 0.0]);
            }
        }
        let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        let mut f = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (v, f)
    }

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
    fn point_source_on_plane_close_to_euclidean() {
        let (v, f) = grid(40, 40, 0.5);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let c = 20 * 41 + 20;
        let d = s.distances(&[c as u32], f64::INFINITY, Method::Fmm);
        let mut err = 0.0;
        for (i, p) in v.iter().enumerate() {
            let e = ((p[0] - 10.0).powi(2) + (p[1] - 10.0).powi(2)).sqrt();
            assert!(d[i] >= e - 1e-9);
            if i != c {
                err += (d[i] - e) / e;
            }
        }
        let mean = err / (v.len() - 1) as f64;
        assert!(mean <= 0.02, "mean rel err {mean}");
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
