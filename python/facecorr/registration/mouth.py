"""Mouth search: move the fitted template's lips onto the scan's before the shape fit (issue 14).

Out of model the blendshape-and-identity fit (:mod:`.expression`) can leave the lips a lip's
height off: on a face whose philtrum is longer than any training face's the template's lips sit
on the philtrum, and the shape fit keeps them there (its closest-point matches slide along the
surface, they never pull a feature across it; BENCHMARKS.md, "Out of model, sixth pass"). The
lips are a relief along the face's vertical axis (upper lip, fissure, lower lip), so a rigid
trimmed ICP of the fitted template's lips (:func:`facecorr.landmarks.pose.surface_icp`), started at
a ladder of vertical offsets, lands on them where they are. A landing is taken only when it is
clearly a better place for the same lips: ≥ ``min_shift`` mm away, a trimmed RMS ≤
``max_rms_ratio`` × the lips' own where they stand, turned by ≤ ``max_angle`` degrees and moved
mostly vertically (measured on the out-of-model test split, landings that turned the lips or
fitted only a little better had read another relief: a chin crease, the nose base). The lips and
the face below them then move by that translation, faded out towards the subnasal (the nose
stays) and sideways; otherwise nothing changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..names import SUBNASAL

#: iBUG-68 indices of the mouth (outer and inner lip contours).
MOUTH_IBUG = tuple(range(48, 68))


@dataclass(frozen=True)
class MouthSearchOptions:
    """Settings of :func:`search_mouth` (mm, degrees)."""

    margin: float = 7.0             # the lips: template vertices this close to an iBUG-68 mouth point
    step: float = 2.5               # vertical offsets of the starts: -reach..reach in these steps
    reach: float = 15.0
    iters: int = 20                 # ICP iterations from each start
    spacing_stride: int = 2         # every n-th lip vertex takes part in the ICP
    # A landing is taken only when it is a move of the lips, not a different reading of the face:
    min_shift: float = 3.0          # its centre lies at least this far from where the lips stand,
    # its trimmed RMS is at most this × the lips' own (about half): at 0.7, 3 of the 350 in-model
    # test scans (sad faces) took wrong landings at 0.62-0.68 (the lips on the chin crease)
    max_rms_ratio: float = 0.55
    max_angle: float = 8.0          # it turned the lips by at most this (lips landing on a nostril
    min_vertical: float = 0.8       # or a chin crease turn), and the move is this much vertical
    # The move (a translation) is whole on the lips and below them, fades out upwards between the
    # top of the upper lip and the subnasal (the nose stays), sideways over ``fade`` mm beyond the
    # mouth's corners and downwards over ``fade`` mm below the lower lip.
    fade: float = 15.0


def _lips(template, margin: float):
    """(ids (R,), centre (3,)): the template's vertices within ``margin`` mm of one of its iBUG-68
    mouth points (the lips and their rims, not the nose base or the chin, whose relief would
    outweigh the lips'), and the mouth's centre (the points' mean), template coordinates."""
    from ..geometry.spatial import KDTree

    ib = np.asarray(template.ibug68)[list(MOUTH_IBUG)]
    ib = ib[ib >= 0]
    v = np.asarray(template.vertices)
    d, _ = KDTree(v[ib]).query(v, distance_upper_bound=margin)
    return np.flatnonzero(np.isfinite(d)), v[ib].mean(axis=0)


def search_mouth(vertices: np.ndarray, template, scan, transform: np.ndarray, options: MouthSearchOptions,
                 exclude: np.ndarray | None = None):
    """Where the scan's lips are, for a fitted template whose lips may stand elsewhere.

    Parameters
    ----------
    vertices : (N, 3) the fitted template (expression fit), scan frame, mm.
    template : the Template (its mouth points and frame: y up).
    scan : Mesh (its :attr:`~facecorr.geometry.mesh.Mesh.surface`).
    transform : (3, 4) the template-to-scan alignment (its linear part gives the face's vertical axis).
    options : MouthSearchOptions.
    exclude : optional (N,) bool, template vertices kept out of the ICP (the inner lip rim).

    Returns
    -------
    (vertices (N, 3), info dict): the template with its mouth region moved onto the lips (the input
    itself when the search finds no better place), and ``shift_mm`` (the lips' centre's move),
    ``rms_ratio`` (best landing's trimmed RMS / the lips' own where they stand), ``angle_deg``
    (its turn), ``vertical`` (|cos| of its move with the face's vertical axis), ``moved`` (bool).
    """
    from ..geometry.icp import surface_icp

    o = options
    ids, centre_t = _lips(template, float(o.margin))
    if exclude is not None:
        ids = ids[~np.asarray(exclude, bool)[ids]]
    pts = np.asarray(vertices, float)[ids[::max(1, int(o.spacing_stride))]]
    if len(pts) < 20:
        return vertices, dict(shift_mm=0.0, rms_ratio=1.0, angle_deg=0.0, vertical=0.0, moved=False)
    up = np.asarray(transform, float)[:, :3] @ np.array([0.0, 1.0, 0.0])
    up /= np.linalg.norm(up)
    offsets = np.arange(-float(o.reach), float(o.reach) + 1e-9, float(o.step))
    eye = np.eye(3)
    here = surface_icp(pts, scan.surface, [(eye, np.zeros(3))], iters=0)[0][2]
    fits = surface_icp(pts, scan.surface, [(eye, d * up) for d in offsets], iters=int(o.iters))
    angles = [float(np.degrees(np.arccos(np.clip((np.trace(f[0]) - 1.0) / 2.0, -1.0, 1.0)))) for f in fits]
    # the best landing that did not turn the lips (a turned one read the relief of something else)
    ok = [i for i in range(len(fits)) if angles[i] <= float(o.max_angle)] or list(range(len(fits)))
    k = min(ok, key=lambda i: fits[i][2])
    r, t, rms, _ = fits[k]
    angle = angles[k]
    centre = pts.mean(axis=0)
    move = centre @ r.T + t - centre
    shift = float(np.linalg.norm(move))
    ratio = rms / max(here, 1e-9)
    vertical = abs(float(move @ up)) / max(shift, 1e-9)
    info = dict(shift_mm=shift, rms_ratio=float(ratio), angle_deg=angle, vertical=vertical, moved=False)
    if (shift < float(o.min_shift) or ratio > float(o.max_rms_ratio) or angle > float(o.max_angle)
            or vertical < float(o.min_vertical)):
        return vertices, info
    w = _move_weights(template, float(o.fade))
    out = np.asarray(vertices, float) + w[:, None] * move
    info["moved"] = True
    return out, info


def _move_weights(template, fade: float) -> np.ndarray:
    """(N,) share of the lips' move each template vertex takes (template frame: x across, y up)."""
    v = np.asarray(template.vertices, float)
    ib = np.asarray(template.ibug68)[list(MOUTH_IBUG)]
    lips = v[ib[ib >= 0]]
    sub_y = v[np.asarray(template.landmark_ids)[SUBNASAL], 1]
    top, bottom = lips[:, 1].max(), lips[:, 1].min()
    half = 0.5 * (lips[:, 0].max() - lips[:, 0].min())
    cx = lips[:, 0].mean()

    def ramp(x):  # 1 at x <= 0, 0 at x >= 1, smooth between
        s = np.clip(x, 0.0, 1.0)
        return 1.0 - s * s * (3.0 - 2.0 * s)

    up = ramp((v[:, 1] - top) / max(sub_y - top, 1e-9))
    down = ramp((bottom - v[:, 1]) / fade)
    side = ramp((np.abs(v[:, 0] - cx) - half) / fade)
    return up * down * side
