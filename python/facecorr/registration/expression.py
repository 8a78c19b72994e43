"""Expression fitting (paper §4.2): blendshape weights α ∈ [0, 1]^K of P(α) = A0 + Σ α_k A_k.

With the template affinely aligned to the scan (T_A = [L | t]), the fitted template is
P(α) = T_A A0 + Σ α_k L A_k in the scan's frame, and the energy is

    E_expr(α) = Σ_r ω_r ⟨NN(p_r(α)) − p_r(α), n(NN(p_r(α)))⟩²

(point-to-plane to the nearest scan vertex). With the nearest neighbours fixed, E_expr is a
quadratic in α with gradient ∂E/∂α_k = −2 Σ_r ω_r ρ_r ⟨L A_k,r, n_r⟩ (ρ_r the residual); each
solve minimises it inside the bounds [0, 1], and the nearest neighbours are re-found after each
solve (ICP). Two bounded solvers: ``solver="newton"`` (default), a projected Newton method with
an active set on the K×K normal equations (exact for this quadratic, a few iterations), and
``solver="lbfgsb"``, scipy's L-BFGS-B with the analytic gradient (the paper's quasi-Newton). They
agree to 1e-6 (tests); the default exists because scipy's L-BFGS-B calls into multi-threaded
OpenBLAS for its 14 unknowns: on our 2 shared cores one call took 0.27 s with 2 BLAS threads vs
2 ms with 1 (measured, 20 repetitions), i.e. 4.4 s vs 0.33 s for a whole expression fit.

Matches (beyond the paper, which takes the nearest scan vertex NN(p_r) and hard tests): the
closest point of the scan's surface, with the scan's normal interpolated there, and each test a
ramp rather than a step (``surface_k``, ``angle_band_deg``, ``distance_band``;
:func:`facecorr.geometry.closest.match_weights`), so that the fit moves continuously with its
input (issue 13, #15: nearest vertices and hard tests moved results by up to 1.5 mm for a 5e-6 mm
change of the scan). ``surface_k=0, angle_band_deg=0, distance_band=0`` is the paper's matching.

Weights ω_r (the paper's two-stage schedule). A match is *valid* if the angle between the normals
of p_r(α) and of its nearest scan vertex is at most φ (upper face) or φ/2 (chin, mouth); invalid
matches get weight 0 (the valid shares below are the sums of the ramped weights). Stage 1: ω_upper = 1, ω_chin = 1 − V_chin^valid / V_chin, ω_mouth = 0.
Stage 2 starts once ≥ 80 % of the chin vertices are valid: ω_mouth = 1 − V_mouth^valid / V_mouth.
The fit stops once ≥ 60 % of the mouth vertices are valid (in stage 2), when α stops changing in
stage 2, or after ``max_rounds`` rounds. The paper does not say what happens when a share is
never reached; here a stage also ends when α stops changing or after ``max_stage_rounds``
rounds. The region weights depend on the valid shares, which depend on α, and the rounds can
flip between two states; a round whose step does not shrink and turns back is halved (damping). As in the paper the weight of a region *grows* with its share of
invalid matches (a badly matched region pulls harder). ``weights="uniform"`` (all ω = 1 on valid
matches, stop when α converges) is the default, and the point-to-plane energy is blended with
30 % point-to-point (``point_to_point=0.3``): jaw opening moves the chin mostly *along* its
surface, which point-to-plane alone does not see (measured: BENCHMARKS.md, "Where the defaults
come from"). ``weights="paper", point_to_point=0`` is the paper's method.

Beyond the paper (defaults; ``identity=None, refine_rigid=False, alpha_prior=0`` is the paper's
fit): the M modes of an identity basis (:mod:`.identity`) are fitted with α as unbounded weights β
under a Gaussian prior (annealed from stiff to ``identity_prior`` so pose and expression settle
first), 6 rigid unknowns re-align the template each round, and a ridge on α keeps unused
blendshapes at 0. All are linear in the unknowns, so each round stays one small bounded
least-squares solve (K + M + 6 ≈ 60 unknowns).

Teeth and mouth interior (the paper's failure case): scans of open mouths show teeth, tongue and
the mouth socket, which the template does not have, and a lip vertex near them would be pulled
inwards. The guards (BENCHMARKS.md: on ICT-model scans with the jaw wide open, lip error 1.6-1.8 mm
with them vs up to 11 mm without):
* the normal test at φ/2 = 40° in the mouth region rejects most of the socket's walls;
* matches farther than ``max_distance`` (mm) are dropped (teeth sit ≥ 5 mm behind the lips);
* scan boundary vertices are never matches (``reject_boundary``): hair, ears and holes' rims;
* template vertices on the inner lip rim (``template.boundary_loops["mouth"]`` and its
  ``lip_rim_rings``-ring) carry no data weight: they have no counterpart on any scan.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..geometry.closest import match_weights
from ..geometry.mesh import Mesh, vertex_normals
from ..geometry.transforms import rotation_angle, rotation_from_vector
from ..options import resolve
from .._core import blend_normal_equations


def rim_mask(template, rings: int) -> np.ndarray:
    """(N,) bool: the template's inner mouth boundary loop grown by ``rings`` edge rings."""
    n = template.n_vertices
    mask = np.zeros(n, dtype=bool)
    loops = getattr(template, "boundary_loops", {}) or {}
    if "mouth" not in loops:
        return mask
    mask[np.asarray(loops["mouth"], dtype=np.int64)] = True
    f = np.asarray(template.faces)
    for _ in range(rings):
        touch = mask[f].any(axis=1)
        mask[f[touch].ravel()] = True
    return mask


@dataclass
class ExpressionFit:
    """Result of :func:`fit_expression`.

    Attributes
    ----------
    alpha : (K,) float64 blending weights in [0, 1].
    vertices : (N, 3) float64, P(α) in the scan's frame, mm.
    rounds : list of dict, per ICP round: stage, region weights, valid fractions, energy.
    transform : (3, 4) the alignment used at the end (refined if ``refine_affine``).
    seconds : float.
    identity_weights : (M,) float64 weights of the identity modes (empty without a basis).
    """

    alpha: np.ndarray
    vertices: np.ndarray
    rounds: list = field(default_factory=list)
    seconds: float = 0.0
    transform: np.ndarray | None = None
    identity_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class ExpressionOptions:
    """Settings of :func:`fit_expression` (lengths in mm, angles in degrees); the module docstring
    explains each choice, BENCHMARKS.md ("Where the defaults come from") the measurements."""

    phi_deg: float = 80.0             # normal test: φ (upper face), φ/2 (chin, mouth)
    chin_start: float = 0.8           # stage 2 starts once this share of the chin is valid (paper)
    mouth_stop: float = 0.6           # the fit stops once this share of the mouth is valid (paper)
    max_rounds: int = 50              # ICP rounds (nearest-vertex ICP creeps; settles by ~50)
    max_stage_rounds: int = 8         # a stage also ends after this many rounds
    alpha_tol: float = 1e-3           # max |Δα| that counts as converged
    # Also converged once the identity prior has annealed and the data energy fell by less than
    # this share over the last ``energy_window`` rounds (0 = off): the ICP's late creep.
    energy_rtol: float = 2e-3
    energy_window: int = 3
    max_distance: float = 10.0        # matches farther than this are dropped (inf = the paper)
    reject_boundary: bool = True      # scan boundary vertices are never matches
    # Matches are closest points on the scan's surface (around the ``surface_k`` nearest vertices;
    # 0 = the nearest vertex, the paper), and the normal, distance and boundary tests are ramps
    # (± ``angle_band_deg``, ``distance_band`` mm below the cap, × (1 − boundary share)), so a
    # tiny change of the input changes the fit a little (issue 13, #15; `geometry.closest`).
    # 1 since issue 17: the triangles around the nearest vertex give the same fit as 3 (region means
    # within 0.5 %, BENCHMARKS.md "Throughput, third pass") at half the query time.
    surface_k: int = 1
    angle_band_deg: float = 10.0
    distance_band: float = 1.0
    lip_rim_rings: int = 1            # no data on the inner lip rim + this many rings (-1 = keep)
    weights: str = "uniform"          # "uniform" or "paper" (the two-stage region schedule)
    solver: str = "newton"            # "newton" (projected, active set) or "lbfgsb" (scipy)
    point_to_point: float = 0.3       # λ: energy Σ ω [(1 − λ) ρ_plane² + λ ‖q − p‖²] (0 = the paper)
    refine_affine: bool = False       # re-solve T_A by least squares after each α solve
    landmark_weight: float = 1.0      # landmarks' weight in that re-solve (× total data weight)
    alpha_prior: float = 1.0          # μ of the ridge μ W ‖α‖² keeping unused blendshapes at 0
    identity_prior: float = 15.0      # μ_id of the identity prior μ_id ‖β‖² (mm²; modes are 1 σ)
    identity_prior_start: float = 1e4  # annealed from here (a stiff start lets pose and expression settle)
    sample_stride: int = 1            # every n-th template vertex carries data
    refine_rigid: bool = True         # 6 more unknowns: a small rigid motion re-solved each round
    # A round's step is halved when it is not smaller than the last one and ("reversal") points
    # back against it: an oscillation; "growth" halves any step not smaller than the last, which
    # also brakes the slow creep of ICP along one direction. When consecutive steps agree (cosine
    # > 0.9) the step is stretched by ``overrelax``.
    damping: str = "reversal"
    overrelax: float = 1.5
    identity_prior_decay: float = 0.5  # the identity prior's factor per round
    # Anderson acceleration of the rounds once the identity prior has annealed (0 = off; n = the
    # last n rounds mixed): the ICP's slow creep is a fixed-point iteration, and extrapolating
    # from its last steps (Walker & Ni 2011; AA-ICP, Pavlov et al. 2018) reaches its end in fewer
    # rounds. An extrapolation whose energy, with its own matches, is above the plain round's is
    # undone and the history restarted (Zhang et al. 2021, "Fast and Robust ICP").
    anderson: int = 5
    # Normal-aware matches (``feature_lambda`` 0 = off; rust/src/soft_match.rs): the closest point
    # moved along its tangent plane towards the scan vertices within ``feature_radius`` mm whose
    # normals match the template vertex's (weights exp(-(|v - p|² + λ² |n_v - n_p|²) / 2τ²), λ =
    # ``feature_lambda`` mm, τ = ``feature_tau`` mm): where the surface bends (lips, eyes, brow
    # ridge) a template feature is drawn to the scan's, a tangential pull closest points lack.
    feature_lambda: float = 0.0
    feature_tau: float = 2.0
    feature_radius: float = 7.0


def box_qp(h, g, x0, lo=0.0, hi=1.0, max_iter=100) -> np.ndarray:
    """Minimise ½ xᵀHx − gᵀx over lo ≤ x ≤ hi (H symmetric positive semi-definite, small).

    Projected Newton with an active set (Bertsekas 1982): variables at a bound whose gradient
    points outwards are held, a Newton step is taken on the others, and an Armijo search along
    the projection arc keeps the decrease. Exact in a few iterations for K ≈ 14.
    """
    x = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    fx = 0.5 * x @ h @ x - g @ x
    for _ in range(max_iter):
        grad = h @ x - g
        free = ~(((x <= lo) & (grad > 0)) | ((x >= hi) & (grad < 0)))
        d = np.zeros_like(x)
        if free.any():
            hf = h[np.ix_(free, free)]
            ridge = 1e-12 * max(float(np.trace(hf)), 1e-300)  # H may be singular (unused shapes)
            d[free] = -np.linalg.solve(hf + ridge * np.eye(len(hf)), grad[free])
        t = 1.0
        while True:
            xn = np.clip(x + t * d, lo, hi)
            fn = 0.5 * xn @ h @ xn - g @ xn
            if fn <= fx + 1e-4 * grad @ (xn - x) or t < 1e-10:
                break
            t *= 0.5
        if np.abs(xn - x).max() < 1e-12:
            break
        x, fx = xn, fn
    return x


class _BlendBasis:
    """The K shape columns (blendshapes, then identity modes) of the fitted template, laid out
    for the per-round products: ``flat`` (3N, K), row 3i + d = coordinate d of vertex i, and
    ``by_coord`` (3, N, K), the same numbers one coordinate at a time."""

    def __init__(self, cols: np.ndarray):  # cols: (K, N, 3)
        self.n_vertices, self.k = cols.shape[1], cols.shape[0]
        self.flat = np.ascontiguousarray(cols.transpose(1, 2, 0).reshape(-1, cols.shape[0]))
        self.by_coord = np.ascontiguousarray(cols.transpose(2, 1, 0))
        for a in (self.flat, self.by_coord):
            a.flags.writeable = False

    def offsets(self, x: np.ndarray) -> np.ndarray:
        """(N, 3) Σ_k x_k A_k for weights x (K,) (template frame)."""
        return (self.flat @ x).reshape(-1, 3)


_BASIS_CACHE: dict = {}


def _shape_basis(template, identity):
    """(A0 (+ the identity mean) (N, 3), :class:`_BlendBasis`), cached for read-only inputs (the
    packaged template and basis): building the layouts costs a few ms per fit."""
    srcs = [np.asarray(template.vertices), np.asarray(template.blendshapes)]
    if identity is not None:
        srcs += [np.asarray(identity.mean), np.asarray(identity.modes)]
    key = tuple(id(a) for a in srcs)
    cacheable = not any(a.flags.writeable for a in srcs)
    hit = _BASIS_CACHE.get(key) if cacheable else None
    if hit is not None:
        return hit[1], hit[2]
    a0 = np.asarray(template.vertices, dtype=np.float64)
    cols = np.asarray(template.blendshapes, dtype=np.float64)
    if identity is not None:
        # identity modes are extra columns: weights unbounded, with a Gaussian prior
        a0 = a0 + identity.mean
        cols = np.concatenate([cols, np.asarray(identity.modes, dtype=np.float64)])
    basis = _BlendBasis(cols)
    if cacheable:
        if len(_BASIS_CACHE) >= 4:
            _BASIS_CACHE.clear()
        _BASIS_CACHE[key] = (srcs, a0, basis)  # srcs kept alive so their ids stay theirs
    return a0, basis


class _WeightedGram:
    """G(w) = Σ_i w_i B_iᵀB_i (K, K) over the template vertices' basis rows B_i (3, K), updated
    from the previous round's weights through the vertices whose weight changed only: between
    ICP rounds a few per cent of the matches flip, so this is ~20x cheaper than the full sum,
    which dominated a round (the point-to-point term's 3N x K rows)."""

    def __init__(self, basis: _BlendBasis):
        self.basis = basis
        self.w = np.zeros(basis.n_vertices)
        self.g = np.zeros((basis.k, basis.k))

    def update(self, w: np.ndarray) -> np.ndarray:
        ch = np.flatnonzero(w != self.w)
        if len(ch):
            dw = (w - self.w)[ch]
            for bc in self.basis.by_coord:
                rows = bc[ch]
                self.g += rows.T @ (rows * dw[:, None])
            self.w = w.copy()
        return self.g


def _normal_equations(basis: _BlendBasis, gram: _WeightedGram, lin, w, da, qn, v, lam, rigid):
    """H, g, c of one ICP round's data energy E(x) = xᵀHx − 2gᵀx + c, with fixed matches.

    E(x) = Σ_i w_i [(1 − λ) (c_i − J_i x)² + λ ‖da_i − S_i x‖²]: S_i = [L B_i | −[v_i]× | I]
    (3, n_x) is the displacement of vertex i per unknown x = (α, β[, ω, t]) in the scan frame
    (L the alignment's linear part, v_i the vertex relative to the rotation centre), J_i = n_iᵀS_i
    its point-to-plane row and c_i = ⟨da_i, n_i⟩ with da_i = q_i − base_i.

    Parameters: w (N,) weights (0 = no match), da (N, 3) mm, qn (N, 3) matched scan normals,
    v (N, 3) mm (C-contiguous float64), lam λ, rigid: include the 6 rigid unknowns. Returns
    ((n_x, n_x), (n_x,), float). All but the point-to-point shape block is one Rust pass over
    the matched vertices (``_core.blend_normal_equations``; numpy reference in the tests).

    The point-to-point block Σ w_i (L B_i)ᵀ(L B_i) is s² G(w) when L = sR (the default similarity
    alignment, kept by the rigid refinement), from :class:`_WeightedGram`; otherwise summed.
    """
    k = basis.k
    h, g, const = blend_normal_equations(basis.flat, np.ascontiguousarray(lin, dtype=np.float64), w, da, qn, v,
                                         float(lam), bool(rigid))
    if lam > 0.0:
        mm = lin.T @ lin
        s2 = float(np.trace(mm)) / 3.0
        if np.abs(mm - s2 * np.eye(3)).max() <= 1e-10 * s2:
            h[:k, :k] += lam * s2 * gram.update(w)
        else:  # a general linear part (the paper's affine alignment): sum it
            act = np.flatnonzero(w > 0.0)
            bc = [b[act] for b in basis.by_coord]
            lw = (lam * w[act])[:, None]
            for a in range(3):
                u = lin[a, 0] * bc[0] + lin[a, 1] * bc[1] + lin[a, 2] * bc[2]
                h[:k, :k] += u.T @ (u * lw)
    return h, g, const


class _Anderson:
    """Anderson acceleration (type II, depth ``m``) of the expression fit's rounds, seen as a
    fixed-point map z -> G(z) of z = (α, β, vec T): the next point is G(z_k) − ΔG γ with γ the
    least-squares fit of the residual f_k = G(z_k) − z_k by the last ``m`` differences ΔF.
    Bounded weights are clipped into their box and T's linear part projected back to a similarity
    (s R: the fit's alignments are similarities, which the point-to-point term relies on)."""

    def __init__(self, m: int, k: int, lo, hi):
        self.m, self.k, self.lo, self.hi = m, k, lo, hi
        self.z, self.g = [], []
        self.pending = None  # (plain α, plain T, plain energy) behind the last extrapolation

    def restart(self):
        self.z, self.g, self.pending = [], [], None

    def check(self, energy_here: float):
        """None if the extrapolated point's energy (with its own matches) is no higher than the
        plain round's; else that round's (α, T), and the history restarts."""
        plain, self.pending = self.pending, None
        if energy_here <= plain[2]:
            return None
        self.restart()
        return plain[0], plain[1]

    def step(self, alpha, t_start, a_plain, t_plain, energy):
        """(α, T) to go on from, after the plain round (α, T_start) -> (a_plain, t_plain)."""
        self.z.append(np.concatenate([alpha, t_start.ravel()]))
        self.g.append(np.concatenate([a_plain, t_plain.ravel()]))
        self.z, self.g = self.z[-(self.m + 1):], self.g[-(self.m + 1):]
        if len(self.z) < 2:
            return a_plain, t_plain
        f = np.array(self.g) - np.array(self.z)
        df, dg = np.diff(f, axis=0), np.diff(np.array(self.g), axis=0)
        gamma, *_ = np.linalg.lstsq(df.T, f[-1], rcond=None)
        z = self.g[-1] - dg.T @ gamma
        if not np.isfinite(z).all():
            self.restart()
            return a_plain, t_plain
        a = np.clip(z[:self.k], self.lo, self.hi)
        t = z[self.k:].reshape(3, 4)
        u, sv, vt = np.linalg.svd(t[:, :3])
        r = u @ vt
        if np.linalg.det(r) < 0:
            self.restart()
            return a_plain, t_plain
        t = np.hstack([float(sv.mean()) * r, t[:, 3:]])
        self.pending = (a_plain, t_plain, energy)
        return a, t


def _refit_affine(p0, q, qn, w, landmarks, landmark_weight):
    """Least-squares 3x4 T minimising Σ w ⟨q − T p0, n⟩² + μ Σ_l ‖T l̄ − l‖² (None if singular)."""
    ph = np.hstack([p0, np.ones((len(p0), 1))])
    a = (qn[:, :, None] * ph[:, None, :]).reshape(len(p0), 12)  # row of ⟨n, T p⟩ in vec(T)
    b = np.einsum("ij,ij->i", qn, q)
    aw = a * w[:, None]
    h = a.T @ aw
    g = aw.T @ b
    ids, pts = landmarks
    ids = np.asarray(ids, dtype=np.int64)
    mu = landmark_weight * float(w.sum()) / max(len(ids), 1)
    lh = np.hstack([p0[ids], np.ones((len(ids), 1))])
    for k in range(3):
        h[4 * k:4 * k + 4, 4 * k:4 * k + 4] += mu * lh.T @ lh
        g[4 * k:4 * k + 4] += mu * lh.T @ np.asarray(pts, dtype=np.float64)[:, k]
    try:
        t = np.linalg.solve(h, g).reshape(3, 4)
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(t).all() or np.linalg.det(t[:, :3]) <= 0:
        return None
    return t


def fit_expression(template, transform, scan: Mesh, landmarks=None, alpha0=None, identity=None, beta0=None,
                   round_offset: int = 0, options: ExpressionOptions | None = None, **overrides) -> ExpressionFit:
    """Fit the blendshape weights of ``template`` to ``scan`` (paper §4.2).

    Parameters
    ----------
    template : facecorr.template.Template (vertices A0, blendshapes A_k, regions, faces).
    transform : (3, 4) the landmark alignment T_A (template frame -> scan frame).
    scan : Mesh, mm; its cached KD-tree, vertex normals and boundary flags are used.
    landmarks : optional (template vertex ids (L,), scan positions (L, 3)) for ``refine_affine``.
    alpha0 : optional (K,) starting weights in [0, 1] (default zeros: the neutral template).
    identity : optional :class:`facecorr.registration.identity.IdentityBasis`: its M modes are
        fitted with α (unbounded weights β with the Gaussian prior ``identity_prior`` × ‖β‖², in
        mm², the modes being one standard deviation each), the template becoming
        A0 + mean + Σ β_m B_m + Σ α_k A_k.
    beta0 : optional (M,) starting identity weights (default zeros: the basis mean).
    round_offset : rounds already done (continuing an earlier fit): the identity prior's
        annealing resumes where it was.
    options : ExpressionOptions (default ``ExpressionOptions()``, each field documented there);
        ``**overrides`` change its fields.

    Returns
    -------
    ExpressionFit
    """
    o = resolve(options, ExpressionOptions, overrides, "fit_expression")
    if o.weights not in ("paper", "uniform"):
        raise ValueError(f"weights must be 'paper' or 'uniform', got {o.weights!r}")
    if o.solver not in ("newton", "lbfgsb"):
        raise ValueError(f"solver must be 'newton' or 'lbfgsb', got {o.solver!r}")
    t0 = time.perf_counter()
    T = np.asarray(transform, dtype=np.float64)
    k_expr = template.n_blendshapes
    a0, basis = _shape_basis(template, identity)
    base = a0 @ T[:, :3].T + T[:, 3]
    gram = _WeightedGram(basis)
    if o.refine_affine and landmarks is None:
        raise ValueError("refine_affine needs the landmarks (template ids, scan positions)")
    faces = np.ascontiguousarray(template.faces, dtype=np.int64)
    k = basis.k
    regions = np.asarray(template.regions)
    upper, chin, mouth = (regions == 0), (regions == 1), (regions == 2)
    angle_req = np.where(upper, o.phi_deg, o.phi_deg / 2.0)
    surface = scan.surface
    keep = np.ones(template.n_vertices, dtype=bool)
    if o.lip_rim_rings >= 0:
        keep &= ~rim_mask(template, o.lip_rim_rings)

    # every sample_stride-th template vertex carries data (1 = all; the fit has K unknowns, not 3N)
    sample = np.zeros(template.n_vertices, dtype=bool)
    sample[:: max(1, int(o.sample_stride))] = True
    data = np.flatnonzero(sample & keep)  # the vertices that can carry data
    lo = np.where(np.arange(k) < k_expr, 0.0, -np.inf)
    hi = np.where(np.arange(k) < k_expr, 1.0, np.inf)
    alpha = np.zeros(k)
    if alpha0 is not None:
        alpha[:k_expr] = np.clip(np.asarray(alpha0, dtype=np.float64), 0.0, 1.0)
    if beta0 is not None and k > k_expr:
        alpha[k_expr:] = np.asarray(beta0, dtype=np.float64)
    stage = 1
    stage_rounds = 0
    prev_step = np.inf
    prev_delta = None
    rounds = []
    aa = _Anderson(int(o.anderson), k, lo, hi) if o.anderson > 0 and not o.refine_affine else None
    for _ in range(int(o.max_rounds)):
        T_start = T
        lin = T[:, :3]
        p = base + basis.offsets(alpha) @ lin.T
        pn = vertex_normals(p, faces)
        # matches of the data-carrying vertices only (the others weigh 0): q, qn 0 elsewhere
        q, qn = np.zeros_like(p), np.zeros_like(p)
        ps = p[data]
        _, _, q[data], dist, qn[data], b_share = surface.closest(ps, int(o.surface_k))
        if o.feature_lambda > 0.0:
            q[data] = surface.soft_targets(ps, pn[data], int(o.surface_k), float(o.feature_radius),
                                           float(o.feature_lambda), float(o.feature_tau))
        w_match = np.zeros(template.n_vertices)
        w_match[data] = match_weights(np.einsum("ij,ij->i", pn[data], qn[data]), dist, b_share, angle_req[data],
                                      o.angle_band_deg, o.max_distance, o.distance_band, o.reject_boundary)
        valid = w_match > 0.0
        # shares of valid matches (weighted: continuous in the input)
        f_chin = float(w_match[chin & sample].mean()) if (chin & sample).any() else 1.0
        f_mouth = float(w_match[mouth & sample].mean()) if (mouth & sample).any() else 1.0
        if o.weights == "paper":
            if stage == 1 and (f_chin >= o.chin_start or stage_rounds >= o.max_stage_rounds):
                stage, stage_rounds, prev_step = 2, 0, np.inf
            elif stage == 2 and stage_rounds >= o.max_stage_rounds:
                rounds.append(dict(stage=stage, f_chin=f_chin, f_mouth=f_mouth, stopped="stage rounds"))
                break
            if stage == 2 and f_mouth >= o.mouth_stop and rounds:
                rounds.append(dict(stage=stage, f_chin=f_chin, f_mouth=f_mouth, stopped="mouth valid"))
                break
            w_region = np.array([1.0, 1.0 - f_chin, (1.0 - f_mouth) if stage == 2 else 0.0])
        else:
            w_region = np.ones(3)
        # only valid matches on the sample count
        w_vert = np.where(sample, w_region[regions] * w_match, 0.0)
        ctr = p.mean(axis=0)
        lam = float(o.point_to_point)
        h, g, const = _normal_equations(basis, gram, lin, w_vert, q - base, qn, p - ctr, lam,
                                        bool(o.refine_rigid))
        n_x = len(g)
        if aa is not None and aa.pending is not None:
            # the energy at the extrapolated point with its own matches, against the plain round's
            x_here = np.concatenate([alpha, np.zeros(n_x - k)])
            back = aa.check(float(x_here @ h @ x_here - 2.0 * g @ x_here + const))
            if back is not None:  # worse: back to the plain round's result, history restarted
                alpha, T = back
                base = a0 @ T[:, :3].T + T[:, 3]
                continue
        w_total = float(w_vert.sum())
        # optional ridge prior μ W ‖α‖² (W = total data weight, so μ is in mm² per vertex)
        # and the identity prior μ_id ‖β‖² (β ~ N(0, 1) a priori; μ_id in mm²), which relaxes
        # geometrically from identity_prior_start to identity_prior
        mu_id = float(o.identity_prior)
        if o.identity_prior_start is not None:
            mu_id = max(mu_id, float(o.identity_prior_start) * float(o.identity_prior_decay) ** (len(rounds) + round_offset))
        ridge = np.where(np.arange(k) < k_expr, float(o.alpha_prior) * w_total, mu_id)
        if o.refine_rigid:
            ridge = np.concatenate([ridge, np.zeros(6)])
            x0 = np.concatenate([alpha, np.zeros(6)])
            lo_x, hi_x = np.concatenate([lo, np.full(6, -np.inf)]), np.concatenate([hi, np.full(6, np.inf)])
        else:
            x0, lo_x, hi_x = alpha, lo, hi
        h_data = h.copy()
        h[np.diag_indices(n_x)] += ridge
        if o.solver == "newton":
            a_new = box_qp(h, g, x0, lo_x, hi_x)
        else:
            def f(a):  # the same quadratic: E(a) = aᵀHa − 2gᵀa + const
                ha = h @ a
                return float(a @ ha - 2.0 * g @ a + const), 2.0 * (ha - g)

            bounds = [(None if np.isinf(a) else a, None if np.isinf(b) else b) for a, b in zip(lo_x, hi_x)]
            from scipy.optimize import minimize  # this solver only: ~0.3 s to import
            a_new = minimize(f, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                             options={"maxiter": 200, "ftol": 1e-12, "gtol": 1e-9}).x
        # the data energy of the solution from the quadratic form (no second pass over the rows)
        energy = max(float(a_new @ h_data @ a_new - 2.0 * g @ a_new + const), 0.0)
        moved = 0.0
        if o.refine_rigid:
            rot, tr = rotation_from_vector(a_new[k:k + 3]), a_new[k + 3:]
            a_new = a_new[:k]
            T = np.hstack([rot @ T[:, :3], (rot @ (T[:, 3] - ctr) + ctr + tr)[:, None]])
            base = a0 @ T[:, :3].T + T[:, 3]
            moved = float(np.linalg.norm(p - ctr, axis=1).max() * rotation_angle(rot) + np.linalg.norm(tr))
        # β is in standard deviations (~10x the spread of α): scaled so that alpha_tol means alike
        delta = a_new - alpha
        step = float(np.abs(delta * np.where(np.arange(k) < k_expr, 1.0, 0.1)).max())
        reverses = prev_delta is not None and float(delta @ prev_delta) < 0.0
        accelerate = (aa is not None and o.weights == "uniform"
                      and (o.identity_prior_start is None or mu_id <= float(o.identity_prior)))
        if accelerate:
            a_new, T = aa.step(alpha, T_start, a_new, T, energy)
            base = a0 @ T[:, :3].T + T[:, 3]
        elif step > 0.9 * prev_step and (o.damping == "growth" or reverses):
            # The valid sets (and with them the paper's region weights) flip back and forth
            # between two states: damp by taking half the step (a convex combination stays in [0, 1]).
            a_new = 0.5 * (alpha + a_new)
            step *= 0.5
        elif o.overrelax > 1.0 and prev_delta is not None and not reverses:
            cos = float(delta @ prev_delta) / max(float(np.linalg.norm(delta) * np.linalg.norm(prev_delta)), 1e-300)
            if cos > 0.9:  # creeping along one direction: go further along it
                a_new = np.clip(alpha + o.overrelax * delta, lo, hi)
        prev_delta = a_new - alpha
        alpha, prev_step = a_new, step
        step = max(step, moved / 10.0)  # 0.01 mm of rigid motion counts like 1e-3 of α
        stage_rounds += 1
        if o.refine_affine:
            t_new = _refit_affine(a0 + basis.offsets(alpha), q, qn, w_vert, landmarks, float(o.landmark_weight))
            if t_new is not None:
                moved = float(np.abs((a0 @ (t_new[:, :3] - T[:, :3]).T) + (t_new[:, 3] - T[:, 3])).max())
                T = t_new
                base = a0 @ T[:, :3].T + T[:, 3]
                step = max(step, moved / 10.0)  # 0.01 mm of motion counts like 1e-3 of α
        rounds.append(dict(stage=stage, w_chin=float(w_region[1]), w_mouth=float(w_region[2]),
                           f_chin=f_chin, f_mouth=f_mouth, n_valid=int(valid.sum()), energy=energy,
                           step=step))
        annealed = o.identity_prior_start is None or mu_id <= float(o.identity_prior)
        w_e = int(o.energy_window)
        if (o.energy_rtol > 0.0 and annealed and len(rounds) > w_e and not (o.weights == "paper" and stage == 1)
                and energy >= (1.0 - float(o.energy_rtol)) * rounds[-1 - w_e]["energy"]):
            rounds[-1]["stopped"] = "energy flat"
            break
        if step < o.alpha_tol:
            if o.weights == "paper" and stage == 1:
                stage = 2  # stage 1 converged without 80 % valid chin matches: fit the mouth anyway
                continue
            rounds[-1]["stopped"] = "converged"
            break
    p = base + basis.offsets(alpha) @ T[:, :3].T
    return ExpressionFit(alpha=alpha[:k_expr], vertices=p, rounds=rounds, seconds=time.perf_counter() - t0,
                         transform=T, identity_weights=alpha[k_expr:])
