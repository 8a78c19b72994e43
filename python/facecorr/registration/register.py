"""The three registration stages on one scan (paper §4): landmark alignment (:mod:`.alignment`),
expression (+ identity) fitting (:mod:`.expression`), shape fitting (:mod:`.shape`, Rust).

:func:`register` runs them; everything is in the scan's frame and millimetres. Every setting is a
field of :class:`RegisterOptions` (which holds the stages' :class:`ExpressionOptions` and
:class:`ShapeFitOptions`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from threadpoolctl import threadpool_limits

from .. import _core
from ..errors import RegistrationError
from ..geometry.mesh import Mesh
from ..options import resolve
from ..names import LANDMARK_NAMES
from .alignment import ALIGN_MODES, align_landmarks, apply_transform
from .expression import ExpressionFit, ExpressionOptions, fit_expression, rim_mask
from .eyes import EyeSearchOptions, search_eyes
from .mouth import MouthSearchOptions, search_mouth
from .nose import NoseSearchOptions, search_nose
from .shape import ShapeFitOptions, fit_shape

__all__ = ["RegistrationResult", "RegisterOptions", "refit_shape", "register"]


@dataclass
class RegistrationResult:
    """Result of :func:`register`.

    Attributes
    ----------
    vertices : (N, 3) float64, the registered template (template vertex order), mm, scan frame.
    alpha : (K,) float64, fitted blendshape weights in [0, 1] (template.blendshape_names order).
    landmarks_registered : dict name -> (3,) mm, the 8 landmarks read off ``vertices``.
    mhd : float, modified Hausdorff distance registered template -> scan vertices, mm.
    timings_s : dict stage -> seconds ("affine", "scan_geometry", "expression", "shape", "mhd",
        "total").
    transform : (3, 4) the landmark alignment T_A (template frame -> scan frame).
    expression_vertices : (N, 3) P(α) after the expression fit, scan frame.
    shape_start : (N, 3) where the shape fit started (after the mouth, eye and nose searches).
    scan_distance : (N,) distance of each registered vertex to its nearest scan vertex, mm.
    details : dict with the per-round / per-solve logs of the stages.
    """

    vertices: np.ndarray
    alpha: np.ndarray
    landmarks_registered: dict
    mhd: float
    timings_s: dict
    transform: np.ndarray | None = None
    expression_vertices: np.ndarray | None = None
    shape_start: np.ndarray | None = None
    scan_distance: np.ndarray | None = None
    details: dict = field(default_factory=dict)

    def implausible(self) -> list:
        """Reasons (list of str, empty if none) to doubt the fit as a whole.

        The expression + identity fit measures how well the model explains the scan: the RMS of
        its final residuals (mm) and ‖β‖², the identity weights' squared norm, which the prior
        makes χ²-distributed with M degrees of freedom for faces like the training faces. Landmarks
        that put the template in a wrong pose force both up (33 bu3dfe test scans: RMS 0.46-0.78
        mm and ‖β‖² 14-46 for M = 40; the one scan whose predicted eye corners were 30-50 mm off:
        2.5 mm and 536). And the MHD: a registration off the scan (landmarks in another frame)
        is far from it whatever the fit says.
        """
        out = []
        if self.mhd > IMPLAUSIBLE_MHD_MM:
            out.append(f"mhd_{self.mhd:.1f}mm")
        rms = self.details.get("fit_rms_mm")
        if rms is not None and rms > IMPLAUSIBLE_RMS_MM:
            out.append(f"fit_rms_{rms:.1f}mm")
        beta = np.asarray(self.details.get("identity_weights", []), dtype=np.float64)
        if len(beta):
            from ..chi2 import chi2_sf  # the χ² tail (scipy.special's chdtrc, without its import)

            if chi2_sf(len(beta), float(beta @ beta)) < IMPLAUSIBLE_IDENTITY_P:
                out.append(f"identity_chi2_{float(beta @ beta):.0f}_of_{len(beta)}")
        return out


#: Thresholds of :meth:`RegistrationResult.implausible`.
IMPLAUSIBLE_RMS_MM = 1.5
#: A correct registration sits on the scan: its MHD is ~1 mm (a cropped border and holes included),
#: one in the wrong place or pose is several mm off.
IMPLAUSIBLE_MHD_MM = 5.0
IMPLAUSIBLE_IDENTITY_P = 1e-6


@dataclass(frozen=True)
class RegisterOptions:
    """Settings of :func:`register`; the stages' own are in ``expression`` and ``shape``.

    ``shape.w_landmark`` is 10 here (the shape fit's landmark term pins the template's landmarks
    to the given points; the paper has none: 0); the pipeline sets it for predicted landmarks
    (:class:`facecorr.pipeline.CorrespondOptions`). Measurements behind each default:
    BENCHMARKS.md, "Where the defaults come from".
    """

    # "similarity" | "affine" (paper) | "similarity+affine" (see alignment.py)
    alignment: str = "similarity"
    fit_expression: bool = True
    fit_shape: bool = True
    # no shape-fit data term on the inner lip rim + this many rings (-1: keep)
    shape_lip_rim_rings: int = 1
    # Starting jawOpen weights of the expression fit; the fit whose lower face is closest to the
    # scan (symmetric trimmed chamfer) wins (from a closed mouth alone the fit stalls on wide-open
    # mouths).
    jaw_starts: tuple = (0.0, 0.3)
    # With two or more jaw_starts: when the best of them leaves a lower-face chamfer above
    # ``jaw_wide_chamfer`` mm (a lower face neither fitted), the expression fit is also started at
    # each of ``jaw_wide_starts``; such a start wins only if its chamfer is lower by the share
    # ``jaw_wide_margin``. Open mouths on faces unlike the model's stalled half-open (ood_test: 3
    # scans' mouths 15-24 -> 1.6-3.3 mm); unconditioned and without the margin the 0.6 start also
    # won on closed sad mouths by 1-8 % and opened them (in model, 5 scans up to 3.6 mm worse). In
    # model the best chamfer stays under 3.1 mm (100 test scans), so it costs nothing there
    # (BENCHMARKS.md, "Out of model, ninth pass").
    jaw_wide_starts: tuple = (0.6,)
    jaw_wide_chamfer: float = 3.5
    jaw_wide_margin: float = 0.1
    # None: every start runs to the end; n: after n rounds only the best start goes on
    jaw_select_rounds: object = 10
    # With jaw_select_rounds: the starts' rounds match every n-th template vertex only (they only
    # have to tell the starts apart; 1: every vertex); the best start goes on with every vertex.
    # 2 makes the expression fit ~30 % faster at region means within 1 % in model and 2 % out of
    # model, but the fit less continuous in its input (a 5e-6 mm change of a scan moved the result
    # by up to 2.1 mm on 35 test scans, 0.06 mm with 1; BENCHMARKS.md, "Throughput, sixth pass").
    jaw_start_stride: int = 1
    # Identity modes fitted with the expression (see identity.py): None, "packaged" (the basis
    # shipped with facecorr), a path or an IdentityBasis; identity_modes keeps the first modes only.
    identity: object = "packaged"
    identity_modes: object = None
    expression: ExpressionOptions = field(default_factory=ExpressionOptions)
    shape: ShapeFitOptions = field(default_factory=lambda: ShapeFitOptions(w_landmark=10.0))
    # Before the shape fit, look for the scan's lips along the face's vertical axis and move the
    # fitted template's mouth onto them when it stands clearly elsewhere (see mouth.py; None: off).
    mouth_search: MouthSearchOptions | None = field(default_factory=MouthSearchOptions)
    # Before the shape fit, fit each eye's region (with an eyeball in the template's eye hole) to
    # the scan from a ladder of widths and move it where its lids fit clearly better (see eyes.py;
    # None: off).
    eye_search: EyeSearchOptions | None = field(default_factory=EyeSearchOptions)
    # Then the lower nose (tip, alae, nostrils) the same way (see nose.py; None: off).
    nose_search: NoseSearchOptions | None = field(default_factory=NoseSearchOptions)

    def __post_init__(self):
        if self.alignment not in ALIGN_MODES:
            raise ValueError(f"alignment must be one of {ALIGN_MODES}, got {self.alignment!r}")


def _lower_face_chamfer(template, vertices, mesh) -> float:
    """Symmetric trimmed (90 %) mean closest-point distance, mm, between the fitted template's
    chin + mouth regions and the scan vertices near them (<= 15 mm): an open mouth that the fit
    missed shows as scan lips far from the template, a wrongly opened one the other way round."""
    from ..geometry.spatial import KDTree

    lower = np.asarray(template.regions) > 0
    d_ts, _ = mesh.kdtree.query(vertices[lower])
    d_ts = np.sort(np.asarray(d_ts))
    # Only scan vertices within 15 mm of a lower-face vertex count, and each of them lies in the
    # lower face's bounding box grown by 15 mm (+ rounding): the others need no query (the same
    # distances are kept, so the same value; ~10 % of a raw scan's vertices are queried).
    low = vertices[lower]
    box = np.all((mesh.vertices >= low.min(axis=0) - 15.001) & (mesh.vertices <= low.max(axis=0) + 15.001), axis=1)
    d_st, i_st = KDTree(vertices).query(mesh.vertices[box]) if box.any() else (np.zeros(0), np.zeros(0, np.int64))
    d_st = np.asarray(d_st)[lower[np.asarray(i_st)] & (np.asarray(d_st) <= 15.0)]
    d_st = np.sort(d_st)
    trim = lambda d: float(d[: max(1, int(0.9 * len(d)))].mean()) if len(d) else np.inf  # noqa: E731
    return trim(d_ts) + trim(d_st)


def _jaw_alpha(names, jaw) -> np.ndarray:
    """(K,) starting expression weights: jawOpen = ``jaw`` (if the template has it), others 0."""
    a0 = np.zeros(len(names))
    if "jawOpen" in names:
        a0[names.index("jawOpen")] = float(jaw)
    return a0


def _fit_expression_multistart(template, transform, mesh, landmarks, jaw_starts, expr_opts: ExpressionOptions,
                               identity=None, select_rounds=None, start_stride: int = 1, wide_starts=(),
                               wide_chamfer: float = np.inf, wide_margin: float = 0.0):
    """:func:`fit_expression` from each starting jawOpen weight; the best by lower-face chamfer.
    When the best chamfer exceeds ``wide_chamfer`` (mm) the ``wide_starts`` are tried too, their
    chamfers counted ``1 + wide_margin`` times.

    With ``select_rounds`` the starts run that many rounds only, and the best one continues alone
    (the identity prior's annealing resumes where it was) up to ``max_rounds`` in all.
    """
    names = list(template.blendshape_names)
    # Single-threaded BLAS throughout: the products here are small and only lose by threading.
    with threadpool_limits(limits=1, user_api="blas"):
        if "jawOpen" not in names or len(jaw_starts) <= 1:
            return fit_expression(template, transform, mesh, landmarks=landmarks, identity=identity,
                                  alpha0=_jaw_alpha(names, jaw_starts[0] if jaw_starts else 0.0), options=expr_opts)
        max_rounds = int(expr_opts.max_rounds)
        coarse = select_rounds is not None and int(start_stride) > 1
        first = expr_opts if select_rounds is None else replace(
            expr_opts, max_rounds=min(int(select_rounds), max_rounds),
            sample_stride=int(start_stride) if coarse else expr_opts.sample_stride)

        def fit_from(jaw):
            fit = fit_expression(template, transform, mesh, landmarks=landmarks, alpha0=_jaw_alpha(names, jaw),
                                 identity=identity, options=first)
            return fit, _lower_face_chamfer(template, fit.vertices, mesh)

        # The starts are independent: one thread each (numpy and the Rust kernels release the
        # GIL; one register(): expression fit 0.54-0.65 s vs 0.7-1.0 s one after the other),
        # but no more threads than facecorr's pool has (a batch worker sharing the cores with
        # others runs them one after the other: the same fits, without oversubscription).
        t0 = time.perf_counter()
        with ThreadPoolExecutor(max_workers=max(1, min(len(jaw_starts), _core.n_threads()))) as pool:
            fits = list(pool.map(fit_from, jaw_starts))
            if wide_starts and min(c for _, c in fits) > float(wide_chamfer):
                # neither start fitted the lower face: perhaps a mouth open wider than they reach
                fits += [(f, c * (1.0 + float(wide_margin))) for f, c in pool.map(fit_from, wide_starts)]
        best = min(fits, key=lambda fs: fs[1])[0]
        done = len(best.rounds)
        # (a coarse start always goes on: it has matched a part of the template only)
        if coarse or (done < max_rounds and not (best.rounds and best.rounds[-1].get("stopped"))):
            rest = fit_expression(template, best.transform, mesh, landmarks=landmarks, alpha0=best.alpha,
                                  identity=identity, beta0=best.identity_weights, round_offset=done,
                                  options=replace(expr_opts, max_rounds=max(max_rounds - done, 1 + int(expr_opts.energy_window))
                                                  if coarse else max_rounds - done))
            rest.rounds = best.rounds + rest.rounds
            best = rest
        best.seconds = time.perf_counter() - t0
        return best


def _identity_basis(spec, n_modes, n_vertices):
    """The IdentityBasis of the ``identity`` option (None, "packaged", a path or a basis)."""
    from .identity import IdentityBasis, load_identity_basis

    if spec is None:
        return None
    basis = spec if isinstance(spec, IdentityBasis) else load_identity_basis(
        None if spec == "packaged" else spec, n_vertices=n_vertices)
    if len(basis.mean) != n_vertices:
        raise RegistrationError(f"identity basis has {len(basis.mean)} vertices, the template {n_vertices}")
    return basis if n_modes is None else basis.truncated(int(n_modes))


def _landmark_array(landmarks) -> np.ndarray:
    if not isinstance(landmarks, dict):
        raise TypeError("landmarks must be a dict name -> (3,) position in mm")
    missing = [n for n in LANDMARK_NAMES if n not in landmarks]
    if missing:
        raise RegistrationError(f"landmarks missing: {', '.join(missing)}")
    a = np.array([np.asarray(landmarks[n], dtype=np.float64).reshape(-1) for n in LANDMARK_NAMES])
    if a.shape != (len(LANDMARK_NAMES), 3):
        raise RegistrationError("every landmark must be a 3-vector (mm)")
    if not np.isfinite(a).all():
        raise RegistrationError("landmarks contain NaN or infinite values")
    return a


def register(mesh: Mesh, landmarks: dict, template=None, options: RegisterOptions | None = None) -> RegistrationResult:
    """Fit the template to a scan: landmark alignment -> expression -> shape (paper §4).

    Parameters
    ----------
    mesh : Mesh, the scan in mm (any pose); its cached KD-tree, normals and boundary are shared by
        every stage.
    landmarks : dict name -> (3,) mm, the 8 landmarks of facecorr.names.LANDMARK_NAMES on the scan.
    template : facecorr.template.Template (default: the packaged one).
    options : RegisterOptions (default ``RegisterOptions()``).

    Returns
    -------
    RegistrationResult (vertices in the scan's frame, mm).
    """
    from ..template import load_template

    t_start = time.perf_counter()
    template = template if template is not None else load_template()
    opts = resolve(options, RegisterOptions, {}, "register")
    if not isinstance(mesh, Mesh):
        raise TypeError("mesh must be a facecorr.Mesh")
    scan_lm = _landmark_array(landmarks)
    ids = np.asarray(template.landmark_ids, dtype=np.int64)
    timings = {}

    t0 = time.perf_counter()
    transform = align_landmarks(np.asarray(template.vertices)[ids], scan_lm, mode=opts.alignment)
    timings["affine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    mesh.kdtree, mesh.surface  # built once here (with the normals and boundary), shared by every stage
    timings["scan_geometry"] = time.perf_counter() - t0

    k = template.n_blendshapes
    details = {}
    identity = _identity_basis(opts.identity, opts.identity_modes, template.n_vertices)
    if opts.fit_expression:
        expr = _fit_expression_multistart(template, transform, mesh, (ids, scan_lm), tuple(opts.jaw_starts),
                                          opts.expression, identity, opts.jaw_select_rounds, opts.jaw_start_stride,
                                          tuple(opts.jaw_wide_starts), opts.jaw_wide_chamfer, opts.jaw_wide_margin)
        transform = expr.transform
        timings["expression"] = expr.seconds
        details["expression_rounds"] = expr.rounds
        details["identity_weights"] = np.asarray(expr.identity_weights).tolist()
        last = next((r for r in reversed(expr.rounds) if "energy" in r), None)
        if last is not None and last["n_valid"] > 0:
            details["fit_rms_mm"] = float(np.sqrt(last["energy"] / last["n_valid"]))
    else:
        expr = ExpressionFit(alpha=np.zeros(k), vertices=apply_transform(transform, template.vertices))
        timings["expression"] = 0.0
    alpha = expr.alpha

    start = expr.vertices
    if opts.fit_shape and opts.mouth_search is not None and opts.fit_expression:
        t0 = time.perf_counter()
        start, details["mouth_search"] = search_mouth(expr.vertices, template, mesh, transform, opts.mouth_search,
                                                      exclude=rim_mask(template, 1))
        timings["mouth_search"] = time.perf_counter() - t0
    if opts.fit_shape and opts.eye_search is not None and opts.fit_expression:
        t0 = time.perf_counter()
        start, details["eye_search"] = search_eyes(start, template, mesh, transform, opts.eye_search)
        timings["eye_search"] = time.perf_counter() - t0
    if opts.fit_shape and opts.nose_search is not None and opts.fit_expression:
        t0 = time.perf_counter()
        start, details["nose_search"] = search_nose(start, template, mesh, transform, opts.nose_search)
        timings["nose_search"] = time.perf_counter() - t0
    if opts.fit_shape:
        vertices = _shape_stage(start, template, mesh, ids, scan_lm, opts, timings, details)
    else:
        timings["shape"] = 0.0
        vertices = expr.vertices
    return _finish(vertices, alpha, transform, expr.vertices, start, mesh, ids, timings, details, t_start)


def _shape_stage(start, template, mesh, ids, scan_lm, opts: RegisterOptions, timings, details) -> np.ndarray:
    """The shape fit from ``start`` (N, 3) onto ``mesh``; logs into ``timings`` and ``details``."""
    tw = None
    if opts.shape_lip_rim_rings >= 0:
        tw = np.where(rim_mask(template, int(opts.shape_lip_rim_rings)), 0.0, 1.0)
    shape = fit_shape(start, template.faces, mesh, anchors=(ids, scan_lm), template_weight=tw, options=opts.shape)
    timings["shape"] = shape.seconds
    details["shape_solves"] = shape.solves
    if not np.isfinite(shape.vertices).all():
        raise RegistrationError("the shape fit diverged (non-finite vertices)")
    return shape.vertices


def _finish(vertices, alpha, transform, expression_vertices, start, mesh, ids, timings, details, t_start):
    """The RegistrationResult of ``vertices``, with its distances to ``mesh``'s vertices."""
    t0 = time.perf_counter()
    scan_distance = np.asarray(mesh.kdtree.query(vertices)[0], dtype=np.float64)
    mhd_value = float(scan_distance.mean())  # the paper's MHD (geometry.spatial.mhd), from the same query
    timings["mhd"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    return RegistrationResult(
        vertices=vertices,
        alpha=np.asarray(alpha, dtype=np.float64),
        landmarks_registered={n: vertices[i].copy() for n, i in zip(LANDMARK_NAMES, ids)},
        mhd=float(mhd_value),
        timings_s=timings,
        transform=transform,
        expression_vertices=expression_vertices,
        shape_start=start,
        scan_distance=scan_distance,
        details=details,
    )


def refit_shape(result: RegistrationResult, mesh: Mesh, landmarks: dict, template=None,
                options: RegisterOptions | None = None) -> RegistrationResult:
    """``result`` with its shape fit redone onto ``mesh`` from the same start.

    The alignment, the expression (+ identity) fit and the mouth, eye and nose searches of
    ``result`` are kept; only the shape fit sees ``mesh`` (e.g. the scan less the rough layer
    of a beard, :mod:`.beard`). ``landmarks`` and ``options`` as given to :func:`register` for
    ``result``; ``scan_distance`` and ``mhd`` are measured to ``mesh``.
    """
    from ..template import load_template

    t_start = time.perf_counter()
    template = template if template is not None else load_template()
    opts = resolve(options, RegisterOptions, {}, "refit_shape")
    if result.shape_start is None:
        raise RegistrationError("the registration has no shape-fit start to refit from")
    scan_lm = _landmark_array(landmarks)
    ids = np.asarray(template.landmark_ids, dtype=np.int64)
    timings = {k: v for k, v in result.timings_s.items() if k not in ("shape", "mhd", "total")}
    details = dict(result.details)
    vertices = _shape_stage(result.shape_start, template, mesh, ids, scan_lm, opts, timings, details)
    out = _finish(vertices, result.alpha, result.transform, result.expression_vertices, result.shape_start,
                  mesh, ids, timings, details, t_start)
    out.timings_s["total"] += sum(v for k, v in result.timings_s.items() if k not in ("shape", "mhd", "total"))
    return out
