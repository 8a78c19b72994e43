//! Shape fitting (paper §4.3, after Allen et al. 2003 / Li et al. 2009): a 3×4 affine transform
//! T_i = [A_i | t_i] per template vertex p_i moves it to p̃_i = A_i p_i + t_i; the transforms
//! minimise
//!
//!   E = ω_data Σ_i w_i ⟨q_i − p̃_i, n_i⟩²                      (point-to-plane, q_i = NN(p̃_i) on the scan)
//!     + ω_smooth Σ_(i,j)∈edges ‖T_i − T_j‖_F²
//!     + ω_rigid Σ_i [ Σ_k<l (a_k·a_l)² + Σ_k (1 − a_k·a_k)² ]   (a_k = columns of A_i)
//!
//! with L-BFGS ([`crate::lbfgs`]) and an analytic gradient evaluated per vertex in parallel.
//!
//! Choices where the paper is vague (measured in BENCHMARKS.md, "Registration (issue 5)"):
//! * **Correspondences.** q_i is the closest point of the scan's *surface* to p̃_i (among the
//!   triangles around its `surface_k` nearest vertices (default 1), then a walk to the closest one;
//!   [`crate::surface`]), n_i the scan's vertex normals interpolated there; `surface_k` = 0 is
//!   the paper's nearest scan vertex. The weight w_i ∈ [0, 1] is the paper's three tests made
//!   ramps ([`match_weight`]): the angle between the deformed template's normal at i and n_i
//!   against `normal_angle_deg` (80°) ± `angle_band_deg`, the distance against `max_distance`
//!   (a `distance_band` wide ramp below it), and × (1 − the boundary share at q_i) (a match on a
//!   scan boundary edge is *dropped*, not moved inwards: a template part beyond the scan's crop
//!   then just follows the smoothness term instead of piling up at the rim). Why ramps and
//!   surface points: with nearest vertices and hard tests a 5e-6 mm change of the scan moved
//!   the result by up to 1.5 mm (issue 13, #15). Bands of 0 and `surface_k` = 0 are the paper.
//! * **Outer / inner loop.** Weight level ℓ = 0, 1, …, `n_levels`−1 uses
//!   ω_smooth = ω_smooth⁰·r^ℓ and ω_rigid = ω_rigid⁰·r^ℓ, r = `relax_factor` (the paper halves:
//!   r = 0.5; default 0.38, which ends 8 levels about as soft as the paper's 12 halvings). Within a level we alternate
//!   (ICP): re-find nearest neighbours and template normals for the current p̃, then run L-BFGS
//!   with those correspondences fixed (≤ `max_iter` iterations, stop at relative energy change
//!   < `rel_tol`, 1e-4 in the paper). When the energy after a solve changes by less than `relax_tol`
//!   relative to the previous solve of the same level ("the energy change is negligible"), or
//!   after `max_icp` solves, the weights are relaxed. The paper gives no last level; relaxing
//!   forever would leave the data term alone (ill-posed), so `n_levels` bounds it.
//! * **Frame.** The template and the scan are translated by the template centroid before
//!   fitting (so T_i's translation part does not depend on where the scan's origin happens to be:
//!   ‖T_i − T_j‖ mixes the linear part, which multiplies coordinates, and the translation). The
//!   returned transforms are expressed back in the input frame.
//! * **Units** are millimetres; the default ω's are the paper's (BU-3DFE is also in mm), and no
//!   rescaling was needed: starting 10x stiffer (ω_smooth⁰ = 200000, 15 levels) or with
//!   ω_rigid 10x larger made the dense error worse on our test scans (1.69 / 1.73 vs 1.66 mm),
//!   i.e. the paper's values already start in the "nearly affine" regime for mm-sized faces.
//! * **Schedule defaults** (8 levels, memory 5, tolerances 1e-3 / 1e-2) were measured against the
//!   paper-literal run (12 levels, 1e-4): same accuracy, about half the work (BENCHMARKS.md);
//!   `max_icp` 2 (was 5): a level's later solves barely moved (issue 17, "Throughput, sixth pass").

use std::sync::Arc;

use rayon::prelude::*;

use crate::lbfgs::{self, LbfgsOptions};
use crate::mesh::vertex_normals;
use crate::surface::{match_weight, Surface};
use crate::vec3::{add, dot, sub};

/// Options of [`fit`]: the paper's weights and the measured schedule (see module docs).
///
/// The Python dataclass `facecorr.registration.shape.ShapeFitOptions` is the source of truth for
/// the default values: it passes every field to the binding, which has no defaults of its own.
/// [`Default`] mirrors it (for Rust callers, tests and benches), and a pytest
/// (`tests/test_shape_fit.py`, via `_core.shape_fit_default_options()`) checks that they agree.
#[derive(Clone, Debug)]
pub struct ShapeFitOptions {
    pub w_data: f64,
    pub w_smooth: f64,
    pub w_rigid: f64,
    /// Factor applied to ω_smooth and ω_rigid at each relaxation (0.5 in the paper).
    pub relax_factor: f64,
    /// Number of weight levels (relaxations + 1).
    pub n_levels: usize,
    /// Maximum nearest-neighbour updates (inner L-BFGS solves) per weight level.
    pub max_icp: usize,
    /// Relax when the relative change of the energy between two solves of a level is below this.
    pub relax_tol: f64,
    /// L-BFGS: maximum iterations per solve (1000 in the paper).
    pub max_iter: usize,
    /// L-BFGS: relative energy change to stop a solve (1e-4 in the paper).
    pub rel_tol: f64,
    /// L-BFGS memory.
    pub memory: usize,
    /// Normal test: a match counts only if the normals differ by at most this angle (degrees).
    pub normal_angle_deg: f64,
    /// Matches farther than this (mm) are dropped (∞ = no cap, the paper; default 5).
    pub max_distance: f64,
    /// Drop matches whose nearest scan vertex is on the scan's boundary (the paper: true).
    pub reject_boundary: bool,
    /// Matches: 0 = the nearest scan vertex (the paper); k ≥ 1 = the closest point on the scan's
    /// surface among the triangles around the k nearest vertices ([`crate::surface`]).
    pub surface_k: usize,
    /// Width of the normal test's ramp (degrees either side of `normal_angle_deg`; 0 = a step).
    pub angle_band_deg: f64,
    /// Width of the distance cap's ramp (mm below `max_distance`; 0 = a step).
    pub distance_band: f64,
    /// Weight of the landmark term (0 = the paper; it is constant over the levels).
    pub w_landmark: f64,
    /// Per template vertex multiplier of the data weight (empty = all 1). Used to switch the
    /// data term off where the template has no counterpart on a scan, e.g. the inner lip rim,
    /// which would otherwise be pulled onto visible teeth (the paper's failure case).
    pub template_weight: Vec<f64>,
    /// Use the block-diagonal preconditioner ([`BlockPreconditioner`]) in L-BFGS.
    pub precondition: bool,
    /// Normal-aware soft matches ([`crate::soft_match`]; 0 = off): λ (mm) of the normal
    /// difference in the match cost, the temperature τ (mm) and the ball radius (mm).
    pub feature_lambda: f64,
    pub feature_tau: f64,
    pub feature_radius: f64,
    /// Weight β of the tangential term w_i β ‖P_i (s_i − p̃_i)‖² (P_i = I − n_i n_iᵀ, s_i the soft
    /// target) beside the point-to-plane residual; used when `feature_lambda` > 0.
    pub w_tangential: f64,
}

impl Default for ShapeFitOptions {
    fn default() -> Self {
        Self {
            w_data: 1.0,
            w_smooth: 20000.0,
            w_rigid: 10.0,
            relax_factor: 0.38,
            n_levels: 8,
            max_icp: 2,
            relax_tol: 1e-2,
            max_iter: 1000,
            rel_tol: 1e-3,
            memory: 5,
            normal_angle_deg: 80.0,
            max_distance: 5.0,
            reject_boundary: true,
            surface_k: 1,
            angle_band_deg: 10.0,
            distance_band: 1.0,
            w_landmark: 0.0,
            template_weight: Vec::new(),
            precondition: true,
            feature_lambda: 0.0,
            feature_tau: 2.0,
            feature_radius: 7.0,
            w_tangential: 0.5,
        }
    }
}

/// Per-solve record of [`fit`].
#[derive(Clone, Debug)]
pub struct SolveRecord {
    pub level: usize,
    pub w_smooth: f64,
    pub w_rigid: f64,
    pub energy: f64,
    pub e_data: f64,
    pub e_smooth: f64,
    pub e_rigid: f64,
    pub e_landmark: f64,
    pub n_valid: usize,
    pub iterations: usize,
    pub evaluations: usize,
    /// Wall seconds spent on nearest neighbours + normals + weights, and in L-BFGS.
    pub seconds_correspond: f64,
    pub seconds_solve: f64,
}

/// Result of [`fit`].
#[derive(Clone, Debug)]
pub struct ShapeFitResult {
    /// Deformed template vertices p̃_i, input frame (mm).
    pub vertices: Vec<[f64; 3]>,
    /// T_i row-major (3×4 → 12 numbers), acting on input-frame coordinates.
    pub transforms: Vec<[f64; 12]>,
    pub solves: Vec<SolveRecord>,
}

/// Vertex adjacency in compressed-row form (both directions of every undirected edge).
#[derive(Clone, Debug)]
pub struct Adjacency {
    pub offsets: Vec<usize>,
    pub neighbours: Vec<u32>,
}

impl Adjacency {
    /// From undirected edges (duplicates and self-loops are dropped).
    pub fn from_edges(n: usize, edges: &[[usize; 2]]) -> Self {
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); n];
        for &[a, b] in edges {
            if a != b {
                lists[a].push(b as u32);
                lists[b].push(a as u32);
            }
        }
        let mut offsets = Vec::with_capacity(n + 1);
        let mut neighbours = Vec::new();
        offsets.push(0);
        for mut l in lists {
            l.sort_unstable();
            l.dedup();
            neighbours.extend_from_slice(&l);
            offsets.push(neighbours.len());
        }
        Self { offsets, neighbours }
    }

    /// From triangles (their edges).
    pub fn from_faces(n: usize, faces: &[[usize; 3]]) -> Self {
        let edges: Vec<[usize; 2]> = faces.iter().flat_map(|f| [[f[0], f[1]], [f[1], f[2]], [f[2], f[0]]]).collect();
        Self::from_edges(n, &edges)
    }

    fn of(&self, i: usize) -> &[u32] {
        &self.neighbours[self.offsets[i]..self.offsets[i + 1]]
    }
}

/// Fixed correspondences of one inner solve: target point q_i, its unit normal n_i, weight w_i;
/// optional landmark anchors (template vertex id, scan position) for the landmark term.
#[derive(Clone, Debug, Default)]
pub struct Correspondences {
    pub target: Vec<[f64; 3]>,
    pub normal: Vec<[f64; 3]>,
    pub weight: Vec<f64>,
    /// Per vertex: Some(scan position) if the vertex is a landmark anchor (usually 8 of them).
    pub anchor: Vec<Option<[f64; 3]>>,
    /// Per vertex the soft target s_i of the tangential term (empty = no tangential term).
    pub tangent: Vec<[f64; 3]>,
}

/// Energy weights of one solve.
#[derive(Clone, Copy, Debug)]
pub struct Weights {
    pub data: f64,
    pub smooth: f64,
    pub rigid: f64,
    pub landmark: f64,
    /// β of the tangential term (relative to the data weight; 0 = none).
    pub tangential: f64,
}

/// Energy parts of [`energy_gradient`]: the weighted total and the unweighted terms.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnergyParts {
    pub total: f64,
    pub data: f64,
    pub smooth: f64,
    pub rigid: f64,
    pub landmark: f64,
}

/// The transform of the identity, row-major 3×4.
pub const IDENTITY: [f64; 12] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];

#[inline]
fn apply(t: &[f64], p: &[f64; 3]) -> [f64; 3] {
    [
        t[0] * p[0] + t[1] * p[1] + t[2] * p[2] + t[3],
        t[4] * p[0] + t[5] * p[1] + t[6] * p[2] + t[7],
        t[8] * p[0] + t[9] * p[1] + t[10] * p[2] + t[11],
    ]
}

/// E and ∇E (written into `grad`, same layout as `x`: 12 numbers per vertex, T_i row-major).
/// Besides the paper's three terms, an optional landmark term
/// E_lmk = Σ_anchors ‖p̃_l − l‖² (Allen et al.'s marker term; ω_landmark = 0 is the paper).
pub fn energy_gradient(
    x: &[f64],
    points: &[[f64; 3]],
    adj: &Adjacency,
    corr: &Correspondences,
    w: Weights,
    grad: &mut [f64],
) -> EnergyParts {
    let parts = grad
        .par_chunks_mut(12)
        .enumerate()
        .with_min_len(256)
        .map(|(i, g)| {
            let t = &x[12 * i..12 * i + 12];
            g.iter_mut().for_each(|v| *v = 0.0);
            // Data: r = <q - T p, n>, dE/dT[k][c] = -2 w r n_k ph_c.
            let p = &points[i];
            let mut e_data = 0.0;
            let wi = corr.weight[i];
            if wi != 0.0 {
                let pt = apply(t, p);
                let (q, n) = (&corr.target[i], &corr.normal[i]);
                let r = dot(sub(*q, pt), *n);
                e_data = wi * r * r;
                let s = -2.0 * w.data * wi * r;
                let ph = [p[0], p[1], p[2], 1.0];
                for k in 0..3 {
                    for c in 0..4 {
                        g[4 * k + c] += s * n[k] * ph[c];
                    }
                }
                // Tangential: β ‖P (s − p̃)‖², P = I − n nᵀ; dE/dp̃ = −2 β P (s − p̃).
                if w.tangential != 0.0 {
                    if let Some(st) = corr.tangent.get(i) {
                        let d = sub(*st, pt);
                        let u = sub(d, crate::vec3::scale(*n, dot(d, *n)));
                        e_data += wi * w.tangential * dot(u, u);
                        let s2 = -2.0 * w.data * wi * w.tangential;
                        for k in 0..3 {
                            for c in 0..4 {
                                g[4 * k + c] += s2 * u[k] * ph[c];
                            }
                        }
                    }
                }
            }
            // Smoothness: each edge is seen from both ends, hence the 1/2 on the energy.
            // Per-entry sums of d and d² over the neighbours (12 independent lanes: vectorised),
            // then one reduction.
            let mut sd = [0.0f64; 12];
            let mut sd2 = [0.0f64; 12];
            for &j in adj.of(i) {
                let tj: &[f64; 12] = x[12 * j as usize..12 * j as usize + 12].try_into().unwrap();
                for c in 0..12 {
                    let d = t[c] - tj[c];
                    sd[c] += d;
                    sd2[c] += d * d;
                }
            }
            for c in 0..12 {
                g[c] += 2.0 * w.smooth * sd[c];
            }
            let e_smooth = 0.5 * sd2.iter().sum::<f64>();
            // Rigidity on the columns a_k = (t[k], t[4+k], t[8+k]) of the linear part.
            let col = |k: usize| [t[k], t[4 + k], t[8 + k]];
            let a = [col(0), col(1), col(2)];
            let mut gram = [[0.0; 3]; 3];
            for k in 0..3 {
                for l in 0..3 {
                    gram[k][l] = dot(a[k], a[l]);
                }
            }
            let e_rigid = gram[0][1] * gram[0][1]
                + gram[0][2] * gram[0][2]
                + gram[1][2] * gram[1][2]
                + (1.0 - gram[0][0]).powi(2)
                + (1.0 - gram[1][1]).powi(2)
                + (1.0 - gram[2][2]).powi(2);
            for k in 0..3 {
                // dE/da_k = 2 Σ_{l≠k} G_kl a_l − 4 (1 − G_kk) a_k
                let mut gk = [0.0; 3];
                for l in 0..3 {
                    let coef = if l == k { -4.0 * (1.0 - gram[k][k]) } else { 2.0 * gram[k][l] };
                    for r in 0..3 {
                        gk[r] += coef * a[l][r];
                    }
                }
                for r in 0..3 {
                    g[4 * r + k] += w.rigid * gk[r];
                }
            }
            // Landmark anchor: dE/dT[k][c] = 2 (p̃ − l)_k ph_c.
            let mut e_lmk = 0.0;
            if let Some(Some(l)) = corr.anchor.get(i) {
                let pt = apply(t, p);
                let ph = [p[0], p[1], p[2], 1.0];
                for k in 0..3 {
                    let dk = pt[k] - l[k];
                    e_lmk += dk * dk;
                    for c in 0..4 {
                        g[4 * k + c] += 2.0 * w.landmark * dk * ph[c];
                    }
                }
            }
            [e_data, e_smooth, e_rigid, e_lmk]
        })
        .reduce(|| [0.0; 4], |a, b| [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]);
    let total = w.data * parts[0] + w.smooth * parts[1] + w.rigid * parts[2] + w.landmark * parts[3];
    EnergyParts { total, data: parts[0], smooth: parts[1], rigid: parts[2], landmark: parts[3] }
}

/// The scan side of the fit: its surface (vertices in a KD-tree, triangles, unit normals,
/// boundary flags), built once.
pub struct ScanTarget {
    surface: Arc<Surface>,
    /// Added to queries (the fit works in the template-centred frame, the surface in its own).
    offset: [f64; 3],
}

impl ScanTarget {
    pub fn new(points: Vec<[f64; 3]>, faces: Vec<[usize; 3]>, normals: Vec<[f64; 3]>, is_boundary: Vec<bool>) -> Self {
        assert!(!points.is_empty(), "scan has no vertices");
        let surface = Surface::new(points, faces, normals, &is_boundary).expect("scan surface construction failed");
        Self::from_surface(Arc::new(surface))
    }

    /// A target over an already built surface (shared, e.g. the scan's cached `Surface`).
    pub fn from_surface(surface: Arc<Surface>) -> Self {
        Self { surface, offset: [0.0; 3] }
    }

    /// The scan vertices (the KD-tree's points).
    pub fn points(&self) -> &[[f64; 3]] {
        self.surface.points()
    }

    /// Correspondences of the deformed template `deformed` with unit normals `normals`: the
    /// closest surface point (or nearest vertex, `surface_k` = 0) and its continuous weight
    /// ([`match_weight`]; see the module docs for the tests applied).
    pub fn correspond(&self, deformed: &[[f64; 3]], normals: &[[f64; 3]], opts: &ShapeFitOptions) -> Correspondences {
        let queries: Vec<[f64; 3]> = deformed.iter().map(|&p| add(p, self.offset)).collect();
        let sp = self.surface.closest_all(&queries, opts.surface_k);
        let mut c = Correspondences { target: Vec::with_capacity(sp.len()), normal: Vec::with_capacity(sp.len()), weight: Vec::with_capacity(sp.len()), anchor: Vec::new(), tangent: Vec::new() };
        if opts.feature_lambda > 0.0 && opts.w_tangential > 0.0 {
            let so = crate::soft_match::SoftMatchOptions { radius: opts.feature_radius, lambda: opts.feature_lambda, tau: opts.feature_tau };
            c.tangent = crate::soft_match::soft_targets(&self.surface, &queries, normals, &sp, &so)
                .into_iter()
                .map(|t| sub(t, self.offset))
                .collect();
        }
        for (i, m) in sp.iter().enumerate() {
            let wm = match_weight(dot(m.normal, normals[i]), m.dist, m.boundary, opts.normal_angle_deg, opts.angle_band_deg,
                                  opts.max_distance, opts.distance_band, opts.reject_boundary);
            c.target.push(sub(m.point, self.offset));
            c.normal.push(m.normal);
            let tw = opts.template_weight.get(i).copied().unwrap_or(1.0);
            c.weight.push(tw * wm);
        }
        c
    }

    /// The same target seen from a frame moved by −`c` (the fit's template-centred frame).
    fn shifted(&self, c: [f64; 3]) -> Self {
        Self { surface: self.surface.clone(), offset: add(self.offset, c) }
    }
}

/// Block-diagonal preconditioner of the shape energy: per vertex, the inverse of
/// D_i + β_i u_i u_iᵀ where u_i = n_i ⊗ [p_i, 1] is the data term's rank-one Hessian block
/// (β_i = 2 ω_data w_i) and D_i is diagonal: 2 ω_smooth deg_i (the smoothness Laplacian's
/// diagonal), 4 ω_rigid on the linear entries (the rigidity term's curvature near a rotation is
/// 2..8 per entry) and 2 ω_landmark ph_c² on anchors. Applied with Sherman-Morrison.
/// Why: the data term's curvature is ~|p|² ≈ 10³ mm² in the linear entries and 1 in the
/// translation, and the smoothness scale changes by 2^12 over the schedule; without it L-BFGS
/// spends its iterations on this scaling (see BENCHMARKS.md for the measured effect).
pub struct BlockPreconditioner {
    dinv: Vec<[f64; 12]>,
    z: Vec<[f64; 12]>, // D⁻¹u
    coef: Vec<f64>,    // β / (1 + β uᵀD⁻¹u)
}

impl BlockPreconditioner {
    pub fn new(points: &[[f64; 3]], adj: &Adjacency, corr: &Correspondences, w: Weights) -> Self {
        let mut pc = Self { dinv: Vec::new(), z: Vec::new(), coef: Vec::new() };
        pc.rebuild(points, adj, corr, w);
        pc
    }

    /// Recompute for new correspondences / weights, reusing the buffers.
    pub fn rebuild(&mut self, points: &[[f64; 3]], adj: &Adjacency, corr: &Correspondences, w: Weights) {
        let n = points.len();
        self.dinv.resize(n, [0.0; 12]);
        self.z.resize(n, [0.0; 12]);
        self.coef.resize(n, 0.0);
        self.dinv
            .par_iter_mut()
            .zip(self.z.par_iter_mut())
            .zip(self.coef.par_iter_mut())
            .enumerate()
            .with_min_len(256)
            .for_each(|(i, ((di, zi), ci))| {
                let p = &points[i];
                let ph = [p[0], p[1], p[2], 1.0];
                let deg = (adj.offsets[i + 1] - adj.offsets[i]) as f64;
                let anchored = matches!(corr.anchor.get(i), Some(Some(_)));
                let tangential = if w.tangential != 0.0 && i < corr.tangent.len() { w.tangential } else { 0.0 };
                for k in 0..3 {
                    for c in 0..4 {
                        let mut d = 2.0 * w.smooth * deg + 1e-9;
                        if c < 3 {
                            d += 4.0 * w.rigid;
                        }
                        if tangential != 0.0 {
                            // the diagonal of the tangential term's block 2 β w (I − n nᵀ) ⊗ ph phᵀ
                            let nk = corr.normal[i][k];
                            d += 2.0 * w.data * corr.weight[i] * tangential * (1.0 - nk * nk) * ph[c] * ph[c];
                        }
                        if anchored {
                            d += 2.0 * w.landmark * ph[c] * ph[c];
                        }
                        di[4 * k + c] = 1.0 / d;
                    }
                }
                let beta = 2.0 * w.data * corr.weight[i];
                if beta > 0.0 {
                    let nn = &corr.normal[i];
                    let mut utdu = 0.0;
                    for k in 0..3 {
                        for c in 0..4 {
                            let u = nn[k] * ph[c];
                            zi[4 * k + c] = di[4 * k + c] * u;
                            utdu += u * zi[4 * k + c];
                        }
                    }
                    *ci = beta / (1.0 + beta * utdu);
                } else {
                    *ci = 0.0;
                }
            });
    }

    /// v ← P v.
    pub fn apply(&self, v: &mut [f64]) {
        v.par_chunks_mut(12).enumerate().with_min_len(256).for_each(|(i, vi)| {
            let (d, z, c) = (&self.dinv[i], &self.z[i], self.coef[i]);
            // (D + βuuᵀ)⁻¹v = D⁻¹v − c (D⁻¹u)(uᵀD⁻¹v), and uᵀD⁻¹v = zᵀv.
            let zv: f64 = if c != 0.0 { (0..12).map(|k| z[k] * vi[k]).sum() } else { 0.0 };
            for k in 0..12 {
                vi[k] = d[k] * vi[k] - c * z[k] * zv;
            }
        });
    }
}

impl lbfgs::Preconditioner for BlockPreconditioner {
    fn apply(&self, v: &mut [f64]) {
        BlockPreconditioner::apply(self, v)
    }
    fn apply_scaled(&self, v: &mut [f64], s: f64) {
        v.par_chunks_mut(12).enumerate().with_min_len(256).for_each(|(i, vi)| {
            let (d, z, c) = (&self.dinv[i], &self.z[i], self.coef[i]);
            let zv: f64 = if c != 0.0 { (0..12).map(|k| z[k] * vi[k]).sum() } else { 0.0 };
            for k in 0..12 {
                vi[k] = s * (d[k] * vi[k] - c * z[k] * zv);
            }
        });
    }
    fn quad(&self, v: &[f64]) -> f64 {
        // vᵀ(D⁻¹ − c zzᵀ)v per block, without writing P v
        v.par_chunks(12)
            .enumerate()
            .with_min_len(256)
            .map(|(i, vi)| {
                let (d, z, c) = (&self.dinv[i], &self.z[i], self.coef[i]);
                let zv: f64 = if c != 0.0 { (0..12).map(|k| z[k] * vi[k]).sum() } else { 0.0 };
                (0..12).map(|k| d[k] * vi[k] * vi[k]).sum::<f64>() - c * zv * zv
            })
            .sum()
    }
}

fn deform(x: &[f64], points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    points.par_iter().enumerate().with_min_len(512).map(|(i, p)| apply(&x[12 * i..12 * i + 12], p)).collect()
}

/// Fit the template (`vertices`, `faces`) to `scan` with the schedule of the module docs.
/// `anchors`: (template vertex id, scan position) pairs for the optional landmark term.
pub fn fit(
    vertices: &[[f64; 3]],
    faces: &[[usize; 3]],
    scan: &ScanTarget,
    anchors: &[(usize, [f64; 3])],
    opts: &ShapeFitOptions,
) -> ShapeFitResult {
    let n = vertices.len();
    assert!(n > 0, "template has no vertices");
    // Work in the template-centred frame.
    let mut c = [0.0; 3];
    for v in vertices {
        for d in 0..3 {
            c[d] += v[d] / n as f64;
        }
    }
    let pts: Vec<[f64; 3]> = vertices.iter().map(|&v| sub(v, c)).collect();
    let shifted = scan.shifted(c);
    let adj = Adjacency::from_faces(n, faces);
    let mut x: Vec<f64> = (0..n).flat_map(|_| IDENTITY).collect();
    // buffers reused by every solve (fresh ~0.5 MB vectors per solve cost a page fault per 4 KiB)
    let mut ws = lbfgs::LbfgsWorkspace::default();
    let mut pc = BlockPreconditioner { dinv: Vec::new(), z: Vec::new(), coef: Vec::new() };
    let lopts = LbfgsOptions { memory: opts.memory, max_iter: opts.max_iter, rel_tol: opts.rel_tol, grad_tol: 1e-12, ..Default::default() };
    let mut solves = Vec::new();
    let tangential = if opts.feature_lambda > 0.0 { opts.w_tangential } else { 0.0 };
    let mut w = Weights { data: opts.w_data, smooth: opts.w_smooth, rigid: opts.w_rigid, landmark: opts.w_landmark, tangential };
    let mut anchor = vec![None; n];
    for &(i, l) in anchors {
        anchor[i] = Some(sub(l, c));
    }
    let mut gbuf = vec![0.0; 12 * n];
    for level in 0..opts.n_levels {
        let mut e_prev = f64::INFINITY;
        for _ in 0..opts.max_icp.max(1) {
            let t_corr = std::time::Instant::now();
            let cur = deform(&x, &pts);
            let normals = vertex_normals(&cur, faces);
            let mut corr = shifted.correspond(&cur, &normals, opts);
            corr.anchor = anchor.clone();
            let n_valid = corr.weight.iter().filter(|&&v| v > 0.0).count();
            let seconds_correspond = t_corr.elapsed().as_secs_f64();
            let t_solve = std::time::Instant::now();
            let energy = |xx: &[f64], g: &mut [f64]| energy_gradient(xx, &pts, &adj, &corr, w, g).total;
            let rep = if opts.precondition {
                pc.rebuild(&pts, &adj, &corr, w);
                lbfgs::minimize_preconditioned_in(&mut ws, energy, &mut x, &lopts, Some(&pc))
            } else {
                lbfgs::minimize_preconditioned_in(&mut ws, energy, &mut x, &lopts, None::<&BlockPreconditioner>)
            };
            let seconds_solve = t_solve.elapsed().as_secs_f64();
            let ep = energy_gradient(&x, &pts, &adj, &corr, w, &mut gbuf);
            let e = ep.total;
            solves.push(SolveRecord {
                level,
                w_smooth: w.smooth,
                w_rigid: w.rigid,
                energy: e,
                e_data: ep.data,
                e_smooth: ep.smooth,
                e_rigid: ep.rigid,
                e_landmark: ep.landmark,
                n_valid,
                iterations: rep.iterations,
                evaluations: rep.evaluations,
                seconds_correspond,
                seconds_solve,
            });
            let negligible = e_prev.is_finite() && (e_prev - e).abs() <= opts.relax_tol * e_prev.abs().max(1e-300);
            e_prev = e;
            if negligible {
                break;
            }
        }
        w.smooth *= opts.relax_factor;
        w.rigid *= opts.relax_factor;
    }
    // Back to the input frame: p̃ = A (p − c) + t + c = A p + (t + c − A c).
    let deformed = deform(&x, &pts);
    let vertices_out = deformed.iter().map(|&p| add(p, c)).collect();
    let transforms = (0..n)
        .map(|i| {
            let mut t = [0.0; 12];
            t.copy_from_slice(&x[12 * i..12 * i + 12]);
            for r in 0..3 {
                let ac = t[4 * r] * c[0] + t[4 * r + 1] * c[1] + t[4 * r + 2] * c[2];
                t[4 * r + 3] += c[r] - ac;
            }
            t
        })
        .collect();
    ShapeFitResult { vertices: vertices_out, transforms, solves }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regular grid patch in the xy plane (spacing h), z from `height`.
    fn grid(nx: usize, ny: usize, h: f64, height: impl Fn(f64, f64) -> f64) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
        crate::fixtures::grid(nx, ny, |i, j| {
            let (x, y) = (i as f64 * h, j as f64 * h);
            [x, y, height(x, y)]
        })
    }

    fn pseudo_random(k: usize) -> f64 {
        let x = ((k as f64 + 1.0) * 12.9898).sin() * 43758.5453;
        x - x.floor() - 0.5
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let (v, f) = grid(5, 4, 2.0, |x, y| 0.1 * x * y);
        let n = v.len();
        let adj = Adjacency::from_faces(n, &f);
        let corr = Correspondences {
            target: (0..n).map(|i| [v[i][0] + pseudo_random(3 * i), v[i][1] + 0.3, v[i][2] + pseudo_random(3 * i + 1)]).collect(),
            normal: (0..n)
                .map(|i| {
                    let m = [pseudo_random(7 * i), pseudo_random(7 * i + 1), 1.0];
                    let l = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
                    [m[0] / l, m[1] / l, m[2] / l]
                })
                .collect(),
            weight: (0..n).map(|i| if i % 5 == 3 { 0.0 } else { 1.0 }).collect(),
            anchor: (0..n).map(|i| if i % 7 == 2 { Some([pseudo_random(11 * i), 1.0, 2.0]) } else { None }).collect(),
            tangent: (0..n).map(|i| [v[i][0] + 0.5 * pseudo_random(5 * i), v[i][1] - 0.2, v[i][2] + 0.3]).collect(),
        };
        let x: Vec<f64> = (0..12 * n).map(|k| IDENTITY[k % 12] + 0.2 * pseudo_random(1000 + k)).collect();
        let w = Weights { data: 1.3, smooth: 7.0, rigid: 2.5, landmark: 0.7, tangential: 0.6 };
        let mut g = vec![0.0; 12 * n];
        energy_gradient(&x, &v, &adj, &corr, w, &mut g);
        let mut scratch = vec![0.0; 12 * n];
        for k in 0..12 * n {
            let h = 1e-6;
            let mut xp = x.clone();
            xp[k] += h;
            let ep = energy_gradient(&xp, &v, &adj, &corr, w, &mut scratch).total;
            xp[k] -= 2.0 * h;
            let em = energy_gradient(&xp, &v, &adj, &corr, w, &mut scratch).total;
            let fd = (ep - em) / (2.0 * h);
            assert!((fd - g[k]).abs() <= 1e-5 * (1.0 + g[k].abs()), "component {k}: fd {fd} analytic {}", g[k]);
        }
    }

    #[test]
    fn identity_has_zero_smooth_and_rigid_energy() {
        let (v, f) = grid(4, 4, 1.0, |_, _| 0.0);
        let n = v.len();
        let adj = Adjacency::from_faces(n, &f);
        let corr = Correspondences { target: v.clone(), normal: vec![[0.0, 0.0, 1.0]; n], weight: vec![1.0; n], anchor: vec![None; n], tangent: Vec::new() };
        let x: Vec<f64> = (0..n).flat_map(|_| IDENTITY).collect();
        let mut g = vec![0.0; 12 * n];
        let e = energy_gradient(&x, &v, &adj, &corr, Weights { data: 1.0, smooth: 1.0, rigid: 1.0, landmark: 1.0, tangential: 0.0 }, &mut g);
        assert_eq!(e, EnergyParts::default());
        assert!(g.iter().all(|&c| c == 0.0));
    }

    #[test]
    fn recovers_a_smooth_bend() {
        // Template: a 60 x 60 mm patch with a nose-like bump (3 mm grid). Scan: the same surface,
        // sampled at 1 mm, rolled isometrically onto a cylinder of radius 60 mm around the y axis
        // and lifted 1 mm: a smooth bend that per-vertex rigid transforms represent exactly, so
        // the known map must be recovered, not just the surface.
        let surf = |x: f64, y: f64| 8.0 * (-((x - 30.0).powi(2) + (y - 32.0).powi(2)) / 60.0).exp() + 0.002 * (y - 30.0).powi(2);
        let radius = 60.0;
        let roll = |p: [f64; 3]| {
            let (u, r) = ((p[0] - 30.0) / radius, radius + p[2]);
            [30.0 + r * u.sin(), p[1], r * u.cos() - radius + 1.0]
        };
        let (tv, tf) = grid(21, 21, 3.0, surf);
        let (sv0, sf) = grid(61, 61, 1.0, surf);
        let sv: Vec<[f64; 3]> = sv0.into_iter().map(roll).collect();
        let sn = vertex_normals(&sv, &sf);
        let bnd: Vec<bool> = (0..sv.len()).map(|k| {
            let (i, j) = (k % 61, k / 61);
            i == 0 || j == 0 || i == 60 || j == 60
        }).collect();
        let scan = ScanTarget::new(sv, sf, sn, bnd);
        let anchors: Vec<(usize, [f64; 3])> = [10 * 21 + 10, 5 * 21 + 5, 5 * 21 + 15, 15 * 21 + 5, 15 * 21 + 15].iter().map(|&i| (i, roll(tv[i]))).collect();
        // Point-to-plane leaves tangential sliding free on the flat parts; five anchors (like the
        // landmarks the pipeline has) pin it. Without them the mean error is ~5 mm here.
        // The paper-literal schedule: 12 levels, tolerances 1e-4 / 1e-3, memory 10, no distance cap.
        let opts = ShapeFitOptions {
            w_landmark: 1.0,
            n_levels: 12,
            rel_tol: 1e-4,
            relax_tol: 1e-3,
            memory: 10,
            max_distance: f64::INFINITY,
            ..Default::default()
        };
        let res = fit(&tv, &tf, &scan, &anchors, &opts);
        let (mut worst, mut mean, mut count, mut off_surface) = (0.0f64, 0.0, 0, 0.0f64);
        for (p0, p) in tv.iter().zip(&res.vertices) {
            if p0[0] < 6.0 || p0[0] > 54.0 || p0[1] < 6.0 || p0[1] > 54.0 {
                continue; // two border rings: no valid matches beyond the scan's boundary
            }
            // Distance to the rolled surface: unroll p (inverse of `roll`) and compare heights.
            let (dx, dz) = (p[0] - 30.0, p[2] - 1.0 + radius);
            let (r, u) = ((dx * dx + dz * dz).sqrt(), dx.atan2(dz));
            off_surface = off_surface.max((r - radius - surf(30.0 + u * radius, p[1])).abs());
            let t = roll(*p0);
            let e = ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt();
            worst = worst.max(e);
            mean += e;
            count += 1;
        }
        mean /= count as f64;
        eprintln!("bend recovery: mean {mean} max {worst} mm, off surface {off_surface} mm");
        assert!(off_surface < 0.2, "off the surface by {off_surface} mm");
        assert!(mean < 1.0 && worst < 2.5, "correspondence error mean {mean} max {worst} mm");
        // The transforms reproduce the returned vertices in the input frame.
        for (i, p) in tv.iter().enumerate() {
            let q = apply(&res.transforms[i], p);
            for d in 0..3 {
                assert!((q[d] - res.vertices[i][d]).abs() < 1e-9);
            }
        }
    }
}

