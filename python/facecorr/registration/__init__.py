"""Registration of the blendshape template onto a scan (paper §4): landmark alignment
(:mod:`.affine`), expression fitting (:mod:`.expression`), shape fitting (:mod:`.shape`, Rust).

:func:`register` runs the three stages; everything is in the scan's frame and millimetres.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from ..errors import RegistrationError
from ..mesh import Mesh
from ..names import LANDMARK_NAMES
from .affine import ALIGN_MODES, align_landmarks, apply_transform
from .expression import EXPRESSION_DEFAULTS, ExpressionFit, fit_expression, rim_mask
from .shape import SHAPE_DEFAULTS, ShapeFit, fit_shape

__all__ = ["RegistrationResult", "register", "align_landmarks", "fit_expression", "fit_shape",
           "REGISTER_DEFAULTS"]


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
    details : dict with the per-round / per-solve logs of the stages.
    """

    vertices: np.ndarray
    alpha: np.ndarray
    landmarks_registered: dict
    mhd: float
    timings_s: dict
    transform: np.ndarray | None = None
    expression_vertices: np.ndarray | None = None
    details: dict = field(default_factory=dict)

    def implausible(self) -> list:
        """Reasons (list of str, empty if none) to doubt the fit as a whole.

        The expression + identity fit measures how well the model explains the scan: the RMS of
        its final residuals (mm) and ‖β‖², the identity weights' squared norm, which the prior
        makes χ²-distributed with M degrees of freedom for faces like the training faces. Landmarks
        that put the template in a wrong pose force both up (33 bu3dfe test scans: RMS 0.46-0.78
        mm and ‖β‖² 14-46 for M = 40; the one scan whose predicted eye corners were 30-50 mm off:
        2.5 mm and 536).
        """
        out = []
        rms = self.details.get("fit_rms_mm")
        if rms is not None and rms > IMPLAUSIBLE_RMS_MM:
            out.append(f"fit_rms_{rms:.1f}mm")
        beta = np.asarray(self.details.get("identity_weights", []), dtype=np.float64)
        if len(beta):
            from scipy.special import chdtrc  # the χ² tail

            if chdtrc(len(beta), float(beta @ beta)) < IMPLAUSIBLE_IDENTITY_P:
                out.append(f"identity_chi2_{float(beta @ beta):.0f}_of_{len(beta)}")
        return out


#: Thresholds of :meth:`RegistrationResult.implausible`.
IMPLAUSIBLE_RMS_MM = 1.5
IMPLAUSIBLE_IDENTITY_P = 1e-6


#: Pipeline options beyond the stages' own (``expression_*`` / ``shape_*`` prefixed keys go to
#: the stages, e.g. ``shape_n_levels=8``, ``expression_max_distance=5``).
REGISTER_DEFAULTS = dict(
    # see affine.py: "similarity" | "affine" (paper) | "similarity+affine"; on 14 synthetic test
    # scans the paper's affine gave a dense error of 3.79 mm vs 2.15 for the similarity.
    alignment="similarity",
    fit_expression=True,
    fit_shape=True,
    # ω of the landmark term in the shape fit (paper: none = 0). 10 measured on 7 synthetic test
    # scans (6706-vertex template): nose 1.84 -> 1.13 mm, eyes 1.06 -> 0.79 mm, dense 2.47 -> 2.42.
    shape_landmark_weight=10.0,
    shape_lip_rim_rings=1,  # no data term on the inner lip rim + this many rings (-1: keep)
    # Starting jawOpen weights of the expression fit; the fit whose lower face is closest to the
    # scan (symmetric trimmed chamfer) wins. From a closed mouth alone the fit stalls on wide-open
    # mouths (surprise, fear: mouth errors of 10-35 mm on 36 of 350 bu3dfe test scans); starting
    # also at 0.3 fixed the 3 such scans examined (mouth 9.5/15.1/11.5 -> 3.0/3.6/6.1 mm).
    jaw_starts=(0.0, 0.3),
    # None: every start runs to the end; n: after n rounds only the best start goes on (70 test
    # scans, 50 rounds: all the way dense 1.486 mm, expression 1.82 s in a 2-process pool; best
    # after 10 rounds 1.489 mm, 1.04 s; after 5 rounds 1.488 mm, 0.97 s).
    jaw_select_rounds=10,
    # Identity modes fitted with the expression (see identity.py): None, "packaged" (the basis
    # shipped with facecorr) or an IdentityBasis; identity_modes keeps the first modes only.
    # 70 bu3dfe test scans, predicted landmarks: dense 2.44 -> 1.68 mm, eyebrows 2.68 / 2.79 ->
    # 1.82 / 1.83, eyes 1.69 / 1.79 -> 1.06 / 1.05, nose 1.36 -> 1.05, mouth 2.54 -> 1.39;
    # 60 modes instead of 40: no change.
    identity="packaged",
    identity_modes=None,
)


def _lower_face_chamfer(template, vertices, mesh, tree) -> float:
    """Symmetric trimmed (90 %) mean closest-point distance, mm, between the fitted template's
    chin + mouth regions and the scan vertices near them (<= 15 mm): an open mouth that the fit
    missed shows as scan lips far from the template, a wrongly opened one the other way round."""
    from ..spatial import KDTree

    lower = np.asarray(template.regions) > 0
    d_ts, _ = tree.query(vertices[lower])
    d_ts = np.sort(np.asarray(d_ts))
    d_st, i_st = KDTree(vertices).query(mesh.vertices)
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


def _fit_expression_multistart(template, transform, mesh, scan_normals, scan_boundary, landmarks, jaw_starts,
                               expr_opts, identity=None, select_rounds=None):
    """:func:`fit_expression` from each starting jawOpen weight; the best by lower-face chamfer.

    With ``select_rounds`` the starts run that many rounds only, and the best one continues alone
    (the identity prior's annealing resumes where it was) up to ``max_rounds`` in all.
    """
    from ..spatial import KDTree

    names = list(template.blendshape_names)
    # Single-threaded BLAS throughout: the products here are small and only lose by threading.
    with threadpool_limits(limits=1, user_api="blas"):
        if "jawOpen" not in names or len(jaw_starts) <= 1:
            return fit_expression(template, transform, mesh, scan_normals=scan_normals,
                                  scan_boundary=scan_boundary, landmarks=landmarks, identity=identity,
                                  alpha0=_jaw_alpha(names, jaw_starts[0] if jaw_starts else 0.0), **expr_opts)
        tree = KDTree(mesh.vertices)
        max_rounds = int(expr_opts.get("max_rounds", EXPRESSION_DEFAULTS["max_rounds"]))
        first = dict(expr_opts)
        if select_rounds is not None:
            first["max_rounds"] = min(int(select_rounds), max_rounds)

        def fit_from(jaw):
            fit = fit_expression(template, transform, mesh, tree=tree, scan_normals=scan_normals,
                                 scan_boundary=scan_boundary, landmarks=landmarks,
                                 alpha0=_jaw_alpha(names, jaw), identity=identity, **first)
            return fit, _lower_face_chamfer(template, fit.vertices, mesh, tree)

        # The starts are independent: one thread each (numpy and the Rust kernels release the
        # GIL; one register(): expression fit 0.54-0.65 s vs 0.7-1.0 s one after the other).
        t0 = time.perf_counter()
        with ThreadPoolExecutor(max_workers=len(jaw_starts)) as pool:
            fits = list(pool.map(fit_from, jaw_starts))
        best = min(fits, key=lambda fs: fs[1])[0]
        done = len(best.rounds)
        if done < max_rounds and not (best.rounds and best.rounds[-1].get("stopped")):
            rest = fit_expression(template, best.transform, mesh, tree=tree, scan_normals=scan_normals,
                                  scan_boundary=scan_boundary, landmarks=landmarks, alpha0=best.alpha,
                                  identity=identity, beta0=best.identity_weights, round_offset=done,
                                  **{**expr_opts, "max_rounds": max_rounds - done})
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


def register(mesh: Mesh, landmarks: dict, template=None, **options) -> RegistrationResult:
    """Fit the template to a scan: landmark alignment -> expression -> shape (paper §4).

    Parameters
    ----------
    mesh : Mesh, the scan in mm (any pose).
    landmarks : dict name -> (3,) mm, the 8 landmarks of facecorr.names.LANDMARK_NAMES on the scan.
    template : facecorr.template.Template (default: the packaged one).
    **options : ``alignment``, ``fit_expression``, ``fit_shape``, ``shape_landmark_weight``,
        ``shape_lip_rim_rings``, ``jaw_starts``, ``jaw_select_rounds``, ``identity``,
        ``identity_modes`` (see :data:`REGISTER_DEFAULTS`), and stage options prefixed by
        ``expression_`` (:data:`facecorr.registration.expression.EXPRESSION_DEFAULTS`) or ``shape_``
        (:data:`facecorr.registration.shape.SHAPE_DEFAULTS`).

    Returns
    -------
    RegistrationResult (vertices in the scan's frame, mm).
    """
    from ..template import load_template

    t_start = time.perf_counter()
    template = template if template is not None else load_template()
    if not isinstance(mesh, Mesh):
        raise TypeError("mesh must be a facecorr.mesh.Mesh")
    opts = dict(REGISTER_DEFAULTS)
    expr_opts, shape_opts = {}, {}
    for key, val in options.items():
        if key in REGISTER_DEFAULTS:
            opts[key] = val
        elif key.startswith("expression_") and key[len("expression_"):] in EXPRESSION_DEFAULTS:
            expr_opts[key[len("expression_"):]] = val
        elif key.startswith("shape_") and key[len("shape_"):] in SHAPE_DEFAULTS:
            shape_opts[key[len("shape_"):]] = val
        else:
            raise TypeError(f"register: unknown option {key!r}")
    if opts["alignment"] not in ALIGN_MODES:
        raise ValueError(f"alignment must be one of {ALIGN_MODES}, got {opts['alignment']!r}")
    scan_lm = _landmark_array(landmarks)
    ids = np.asarray(template.landmark_ids, dtype=np.int64)
    timings = {}

    t0 = time.perf_counter()
    transform = align_landmarks(np.asarray(template.vertices)[ids], scan_lm, mode=opts["alignment"])
    timings["affine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    scan_normals = mesh.vertex_normals
    scan_boundary = mesh.is_boundary
    timings["scan_geometry"] = time.perf_counter() - t0

    k = template.n_blendshapes
    details = {}
    identity = _identity_basis(opts["identity"], opts["identity_modes"], template.n_vertices)
    if opts["fit_expression"]:
        expr = _fit_expression_multistart(template, transform, mesh, scan_normals, scan_boundary, (ids, scan_lm),
                                          tuple(opts["jaw_starts"]), expr_opts, identity,
                                          opts["jaw_select_rounds"])
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

    if opts["fit_shape"]:
        tw = None
        if opts["shape_lip_rim_rings"] >= 0 and "template_weight" not in shape_opts:
            tw = np.where(rim_mask(template, int(opts["shape_lip_rim_rings"])), 0.0, 1.0)
        if "template_weight" not in shape_opts:
            shape_opts["template_weight"] = tw
        if "w_landmark" not in shape_opts:
            shape_opts["w_landmark"] = float(opts["shape_landmark_weight"])
        shape = fit_shape(expr.vertices, template.faces, mesh, anchors=(ids, scan_lm), scan_normals=scan_normals,
                          scan_boundary=scan_boundary, **shape_opts)
        timings["shape"] = shape.seconds
        details["shape_solves"] = shape.solves
        vertices = shape.vertices
    else:
        shape = ShapeFit(vertices=expr.vertices, transforms=np.zeros((0, 3, 4)))
        timings["shape"] = 0.0
        vertices = expr.vertices
    if not np.isfinite(vertices).all():
        raise RegistrationError("the shape fit diverged (non-finite vertices)")

    t0 = time.perf_counter()
    from ..evaluate import mhd

    mhd_value = mhd(vertices, mesh.vertices)
    timings["mhd"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    return RegistrationResult(
        vertices=vertices,
        alpha=np.asarray(alpha, dtype=np.float64),
        landmarks_registered={n: vertices[i].copy() for n, i in zip(LANDMARK_NAMES, ids)},
        mhd=float(mhd_value),
        timings_s=timings,
        transform=transform,
        expression_vertices=expr.vertices,
        details=details,
    )
