"""Generalized Procrustes alignment of many shapes in correspondence (rigid or similarity).

Every shape is an (N, 3) array with the same vertex order. :func:`generalized_procrustes`
alternates fitting each shape onto the current mean (all shapes at once: one batched 3x3 SVD per
iteration) and re-averaging, until the mean stops moving. Transforms are stored as
``aligned = s * shape @ R.T + t``, the convention of :func:`facecorr.geometry.transforms.kabsch`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ProcrustesResult:
    """The outcome of :func:`generalized_procrustes`.

    Attributes
    ----------
    aligned : (S, N, 3) float64, every shape after its transform (mm when the input was mm).
    mean : (N, 3) float64, the mean of ``aligned``.
    rotations : (S, 3, 3) proper rotations R, scales : (S,) s (all 1 for a rigid alignment),
    translations : (S, 3) t, with ``aligned[i] = scales[i] * shapes[i] @ rotations[i].T + translations[i]``.
    iterations : int, the mean-update iterations run; converged : bool.
    """

    aligned: np.ndarray
    mean: np.ndarray
    rotations: np.ndarray
    scales: np.ndarray
    translations: np.ndarray
    iterations: int
    converged: bool


def centroid_size(points) -> np.ndarray:
    """Root of the summed squared distances to the centroid: (..., N, 3) -> (...,) (mm)."""
    p = np.asarray(points, dtype=np.float64)
    c = p - p.mean(axis=-2, keepdims=True)
    return np.sqrt(np.einsum("...nj,...nj->...", c, c))


def fit_onto(centred, target, *, scale: bool):
    """Batched Kabsch / Umeyama: R (S, 3, 3) and s (S,) minimising ``|| s X_i R^T - target ||``.

    ``centred`` (S, N, 3) and ``target`` (N, 3) must both have their centroid at the origin
    (then the best translation is zero). Reflections are never allowed.
    """
    h = np.matmul(centred.transpose(0, 2, 1), target)  # sum_n x_n y_n^T per shape (batched BLAS)
    u, sig, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("sji,skj->sik", vt, u)))  # det(V U^T)
    d[d == 0] = 1.0
    fix = np.ones((len(h), 3))
    fix[:, 2] = d
    rot = np.einsum("sji,sj,skj->sik", vt, fix, u)  # V diag(fix) U^T
    if not scale:
        return rot, np.ones(len(h))
    ss = np.square(centred).sum(axis=(1, 2))
    return rot, np.einsum("sj,sj->s", sig, fix) / np.maximum(ss, 1e-300)


def _transformed(centred, rot, s) -> np.ndarray:
    """(S, N, 3): ``s_i * X_i @ R_i.T`` for every shape."""
    return np.matmul(centred, rot.transpose(0, 2, 1)) * s[:, None, None]


def generalized_procrustes(shapes, *, scale: bool = False, reference=None, max_iterations: int = 100,
                           tolerance: float = 1e-9) -> ProcrustesResult:
    """Align ``shapes`` (S, N, 3) to their common mean.

    Parameters
    ----------
    shapes : (S, N, 3) float, S >= 1 shapes in correspondence (mm), each in its own pose.
    scale : False for a rigid alignment (rotation + translation: sizes are kept and are part of
        the shape variation); True for a similarity alignment (also a scale per shape: size is
        removed). With ``scale`` the mean is kept at the average centroid size of the inputs, so
        the result stays in mm.
    reference : optional (N, 3): the final mean is turned (rigidly) onto this shape and moved to
        its centroid, e.g. the template's rest pose so that the model is drawn front-on. Default:
        the first shape's pose, centred at the origin.
    max_iterations, tolerance : the mean update stops when it moves by less than ``tolerance``
        times its centroid size (RMS over the vertices), or after ``max_iterations``.

    Returns
    -------
    ProcrustesResult
    """
    x = np.asarray(shapes, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or len(x) < 1 or x.shape[1] < 3:
        raise ValueError(f"generalized_procrustes: need (S>=1, N>=3, 3) shapes, got {x.shape}")
    centroids = x.mean(axis=1)
    c = x - centroids[:, None, :]
    sizes = centroid_size(c)
    ref, it, converged = procrustes_mean(
        c[0], sizes, lambda target: _transformed(c, *fit_onto(c, target, scale=scale)).mean(axis=0),
        scale=scale, max_iterations=max_iterations, tolerance=tolerance)
    rot, s = fit_onto(c, ref, scale=scale)
    r0, shift = final_pose(ref, reference)
    rot = np.einsum("ij,sjk->sik", r0, rot)
    aligned = _transformed(c, rot, s) + shift
    # aligned = s R (x - c) + shift = s x R^T + (shift - s R c)
    translations = shift - s[:, None] * np.einsum("sij,sj->si", rot, centroids)
    return ProcrustesResult(aligned=aligned, mean=aligned.mean(axis=0), rotations=rot, scales=s,
                            translations=translations, iterations=it, converged=converged)


def procrustes_mean(first, sizes, fitted_mean, *, scale: bool, max_iterations: int = 100,
                    tolerance: float = 1e-9):
    """The mean update of :func:`generalized_procrustes`, whatever holds the shapes.

    Parameters
    ----------
    first : (N, 3) the first shape, centred (its pose starts the mean).
    sizes : (S,) every shape's centroid size (mm).
    fitted_mean : callable ``(N, 3) target -> (N, 3)``: the mean of every centred shape fitted onto
        ``target`` (:func:`fit_onto`, then ``s X R^T``). Locally one batched product; on a Dask
        cluster each worker fits its chunk of shapes (:mod:`facecorr.model.distributed`).
    scale, max_iterations, tolerance : as in :func:`generalized_procrustes`.

    Returns
    -------
    (mean (N, 3) centred, iterations int, converged bool)
    """
    sizes = np.asarray(sizes, dtype=np.float64)
    target_size = float(sizes.mean())
    ref = np.array(first, dtype=np.float64)
    if scale:
        ref *= target_size / max(float(sizes[0]), 1e-300)
    converged, it = False, 0
    for it in range(1, max_iterations + 1):
        mean = np.asarray(fitted_mean(ref), dtype=np.float64)
        if scale:  # the mean's size is free under similarity: hold it at the inputs' average
            mean = mean * (target_size / max(float(centroid_size(mean)), 1e-300))
        moved = float(np.sqrt(np.sum((mean - ref) ** 2))) / max(float(centroid_size(mean)), 1e-300)
        ref = mean
        if moved < tolerance:
            converged = True
            break
    return ref, it, converged


def final_pose(mean, reference=None):
    """(R0 (3, 3), shift (3,)): the turn of the converged ``mean`` (centred, (N, 3)) onto
    ``reference`` (N, 3) and its centroid; without ``reference``: identity and zero."""
    if reference is None:
        return np.eye(3), np.zeros(3)
    from ..geometry.transforms import kabsch

    ref_pts = np.asarray(reference, dtype=np.float64)
    if ref_pts.shape != mean.shape:
        raise ValueError(f"generalized_procrustes: reference is {ref_pts.shape}, shapes are {mean.shape}")
    r0, _ = kabsch(mean, ref_pts)
    return r0, ref_pts.mean(axis=0)
