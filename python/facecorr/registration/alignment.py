"""Landmark alignment of the template onto a scan (paper §4.1).

The paper finds the 3x4 matrix T_A minimising E_lnd = Σ_i ‖T_A l̄_i − l_i‖² (template landmarks
l̄_i, scan landmarks l_i) by a quasi-Newton method from the identity: :func:`affine_quasi_newton`
(scipy BFGS with the analytic gradient). E_lnd is a linear least-squares problem, so the answer is
also available in closed form (:func:`affine_lstsq`, used by the tests as the check).

Why a similarity is the default (``mode="similarity"``): the 8 landmarks (eye corners, subalare,
nose tip, subnasal) lie in a thin slab across the middle of the face; the full affine fit of
12 parameters to 24 numbers is poorly determined along the face's depth and its vertical
direction, and a few millimetres of landmark error become shear and anisotropic scale of the
whole template (its chin and forehead swing far from the scan). Umeyama's similarity (rotation,
uniform scale, translation; 7 parameters; :func:`similarity_umeyama`) cannot shear; the shape
fit absorbs the remaining per-subject anisotropy. ``mode="affine"`` is the paper's choice and
``mode="similarity+affine"`` refines an Umeyama start by the quasi-Newton affine fit with a
penalty pulling it towards that similarity (weight ``shear_penalty``, per unit of matrix entry²).
Measured end to end in BENCHMARKS.md ("Registration (issue 5)").
"""

from __future__ import annotations

import numpy as np

from ..errors import RegistrationError
from ..geometry.transforms import apply_transform, as_matrix, kabsch


def _check(src, dst):
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise ValueError(f"landmarks must be two (L, 3) arrays of the same shape, got {src.shape} and {dst.shape}")
    if len(src) < 4:
        raise ValueError(f"at least 4 landmarks are needed, got {len(src)}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("landmarks contain NaN or infinite values")
    return src, dst


def landmark_energy(t, src, dst) -> float:
    """E_lnd = Σ ‖T src_i − dst_i‖² (mm²)."""
    r = apply_transform(t, src) - dst
    return float(np.sum(r * r))


def affine_lstsq(src, dst) -> np.ndarray:
    """Closed-form least-squares 3x4 affine transform mapping ``src`` (L, 3) onto ``dst`` (L, 3)."""
    src, dst = _check(src, dst)
    h = np.hstack([src, np.ones((len(src), 1))])
    sol, *_ = np.linalg.lstsq(h, dst, rcond=None)
    return sol.T.copy()


def affine_quasi_newton(src, dst, start=None, prior=None, prior_weight=0.0) -> np.ndarray:
    """The paper's §4.1: minimise E_lnd over the 12 entries of T_A by BFGS from ``start``.

    Parameters
    ----------
    src, dst : (L, 3) template and scan landmarks, mm.
    start : (3, 4) start (default: the identity, as in the paper).
    prior, prior_weight : optional (3, 4) transform and weight w adding w ‖T − prior‖² (used by
        ``mode="similarity+affine"`` to keep the fit near a similarity).

    Returns
    -------
    (3, 4) float64 transform.
    """
    src, dst = _check(src, dst)
    h = np.hstack([src, np.ones((len(src), 1))])
    # Centre and scale the problem so BFGS sees comparable curvature in the linear and the
    # translation entries (the minimiser is the same; coordinates are ~100 mm).
    x0 = np.eye(3, 4) if start is None else np.asarray(start, dtype=np.float64)
    pr = np.zeros((3, 4)) if prior is None else np.asarray(prior, dtype=np.float64)
    scale = float(np.abs(h).max())

    def f(x):
        t = x.reshape(3, 4) * np.array([1, 1, 1, scale])
        r = h @ t.T - dst
        d = t - pr
        e = float(np.sum(r * r) + prior_weight * np.sum(d * d))
        g = (2.0 * r.T @ h + 2.0 * prior_weight * d) * np.array([1, 1, 1, scale])
        return e / scale**2, g.ravel() / scale**2

    x_start = (x0 / np.array([1, 1, 1, scale])).ravel()
    from scipy.optimize import minimize  # only on this path: scipy.optimize costs ~0.3 s to import

    res = minimize(f, x_start, jac=True, method="BFGS", options={"gtol": 1e-12, "maxiter": 1000})
    return res.x.reshape(3, 4) * np.array([1, 1, 1, scale])


def similarity_umeyama(src, dst) -> np.ndarray:
    """Least-squares similarity (rotation, uniform scale, translation; Umeyama 1991) as a 3x4.

    Raises RegistrationError if the landmarks are degenerate (all collinear or coincident).
    """
    src, dst = _check(src, dst)
    try:
        r, scale, t = kabsch(src, dst, with_scale=True)
    except ValueError as e:
        raise RegistrationError(f"the landmarks are degenerate ({e}): the alignment is undetermined") from None
    return as_matrix(r, t, scale)


ALIGN_MODES = ("similarity", "affine", "similarity+affine")


def align_landmarks(template_landmarks, scan_landmarks, mode: str = "similarity", shear_penalty: float = 50.0) -> np.ndarray:
    """The 3x4 transform taking the template's landmarks onto the scan's (see the module docs).

    Parameters
    ----------
    template_landmarks, scan_landmarks : (L, 3) mm, corresponding rows.
    mode : "similarity" (default), "affine" (the paper: quasi-Newton from the identity) or
        "similarity+affine".
    shear_penalty : weight of ‖T − T_similarity‖² in "similarity+affine" (mm² per unit²).

    Returns
    -------
    (3, 4) float64; raises RegistrationError if it mirrors the template (det < 0) or is degenerate.
    """
    if mode not in ALIGN_MODES:
        raise ValueError(f"unknown alignment mode {mode!r}; expected one of {ALIGN_MODES}")
    if mode == "similarity":
        t = similarity_umeyama(template_landmarks, scan_landmarks)
    elif mode == "affine":
        t = affine_quasi_newton(template_landmarks, scan_landmarks)
    else:
        sim = similarity_umeyama(template_landmarks, scan_landmarks)
        t = affine_quasi_newton(template_landmarks, scan_landmarks, start=sim, prior=sim, prior_weight=shear_penalty)
    det = float(np.linalg.det(t[:, :3]))
    if not np.isfinite(t).all() or det <= 1e-9:
        raise RegistrationError(
            f"landmark alignment is degenerate or mirrored (det {det:.3g}); check the landmarks' left/right order")
    return t
