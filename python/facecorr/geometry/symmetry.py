"""Mirror symmetry of a scan about a plane: how asymmetric the scan is about the plane a
registration puts the face's midline in, and the plane the scan itself is most symmetric about.

Why: a face is close to mirror-symmetric about its midsagittal plane, whatever the expression
(a few mm of asymmetry at most), while a registration turned about the viewing axis puts its
midline 20-80° off that plane. Such fits are the start search's wrong poses on unusual faces in
strong expressions, and the fit's own residual does not tell them from right ones (BENCHMARKS.md,
"Out of model, sixteenth pass"). The scan's reflection across the fit's mid-plane does.
"""

from __future__ import annotations

import numpy as np

from .transforms import axis_angle

__all__ = ["mirror_asymmetry", "symmetry_plane", "face_sample"]


def face_sample(points, centre, radius: float, max_points: int = 4000) -> np.ndarray:
    """(m, 3) the scan vertices within ``radius`` mm of ``centre`` (3,), every k-th of them so that
    m ≤ ``max_points`` (deterministic: the vertex order decides)."""
    p = np.asarray(points, dtype=np.float64)
    sel = p[np.sum((p - np.asarray(centre, dtype=np.float64)) ** 2, axis=1) < radius * radius]
    step = max(1, int(np.ceil(len(sel) / max_points)))
    return sel[::step]


def _reflect(p, centre, normal):
    return p - 2.0 * ((p - centre) @ normal)[:, None] * normal


def mirror_asymmetry(sample, surface, centre, normal, keep: float = 0.8) -> float:
    """Trimmed RMS (mm) of the distances from ``sample`` (m, 3) reflected across the plane through
    ``centre`` (3,) with unit ``normal`` (3,) to the scan's surface (``surface``,
    :attr:`facecorr.geometry.mesh.Mesh.surface`: the closest point on its triangles, so that a
    coarse scan's vertex spacing does not count as asymmetry): the ``keep`` share of smallest
    distances counts (holes, hair and a crop's uneven border leave some points without a mirror
    image). inf when the sample is empty."""
    if len(sample) == 0:
        return float("inf")
    n = np.asarray(normal, dtype=np.float64)
    refl = _reflect(np.asarray(sample, dtype=np.float64), np.asarray(centre, dtype=np.float64), n / np.linalg.norm(n))
    d = np.asarray(surface.closest(np.ascontiguousarray(refl), 1)[3], dtype=np.float64)
    d = np.sort(d)[: max(1, int(keep * len(d)))]
    return float(np.sqrt(np.mean(d * d)))


def symmetry_plane(sample, surface, centre, normal, axis, angles_deg=(0, 20, -20, 40, -40, 60, -60, 80, -80),
                   keep: float = 0.8, iters: int = 20):
    """The plane through (about) ``centre`` that the scan is most mirror-symmetric about.

    Mirror ICP: ``sample`` reflected across a start plane is fitted rigidly onto the scan's
    surface (trimmed point-to-plane ICP, :func:`facecorr.geometry.icp.surface_icp`); the
    reflection followed by that motion is an improper isometry, whose plane (the eigenvector of
    its linear part's symmetric half with eigenvalue ≈ −1, and half its displacement of the
    origin along it) is the refined plane. The start planes are ``normal`` turned about ``axis``
    (3,) (the face's forward direction) by each of ``angles_deg``, all through ``centre``.

    Parameters: sample (m, 3) mm (scan vertices, e.g. :func:`face_sample`), surface the scan's
    :attr:`facecorr.geometry.mesh.Mesh.surface`; centre, normal,
    axis (3,). Returns (unit normal (3,), point on the plane (3,), its :func:`mirror_asymmetry` in
    mm), the best over the starts and ``normal``'s own plane; the normal's sign agrees with
    ``normal``.
    """
    from .icp import surface_icp

    c0 = np.asarray(centre, dtype=np.float64)
    n0 = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    ax = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    h0 = np.eye(3) - 2.0 * np.outer(n0, n0)
    mirrored = _reflect(np.asarray(sample, dtype=np.float64), c0, n0)
    starts = []
    for a in angles_deg:
        na = axis_angle(ax, np.radians(float(a))) @ n0
        r = (np.eye(3) - 2.0 * np.outer(na, na)) @ h0  # two reflections through c0: a rotation about c0
        starts.append((r, c0 - r @ c0))
    best = (n0, c0, mirror_asymmetry(sample, surface, c0, n0, keep))
    for r, t, _, _ in surface_icp(mirrored, surface, starts, iters=int(iters), keep=keep):
        lin = r @ h0
        w, v = np.linalg.eigh(0.5 * (lin + lin.T))
        n = v[:, 0]
        if w[0] > -0.5:  # not a reflection (cannot happen for a proper r; guards rounding)
            continue
        origin_image = r @ (2.0 * (c0 @ n0) * n0) + t
        c = c0 - (c0 @ n - 0.5 * (origin_image @ n)) * n
        e = mirror_asymmetry(sample, surface, c, n, keep)
        if e < best[2]:
            best = (n if n @ n0 >= 0.0 else -n, c, e)
    return best
