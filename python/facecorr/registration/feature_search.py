"""Feature search: fit one feature of the fitted template (an eye, the lower nose) to the scan's
from a ladder of sizes, before the shape fit (issue 14; used by :mod:`.eyes` and :mod:`.nose`).

Out of model the expression-and-identity fit places a feature by the face model's own shape: on a
face whose eyes or nose are narrower or wider than any training face's, the template's lids or
alae end millimetres beside the scan's, and the shape fit keeps them there (its closest-point
matches slide along the surface; they never pull a feature across it). A feature with relief of
its own (lids around an eyeball, alae and nostrils) is found again by a trimmed rigid ICP
(:func:`facecorr.geometry.icp.surface_icp`) of the template vertices near it, started at a ladder
of widths and heights (a scale along the face's x / y axes about the feature's centre); a landing
clearly better than where the feature stands moves it, faded out around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FeatureSearchOptions:
    """Settings of :func:`fit_feature` (mm; scales are factors along the face's x / y axes).
    :class:`facecorr.registration.eyes.EyeSearchOptions` and
    :class:`facecorr.registration.nose.NoseSearchOptions` give each feature its defaults."""

    margin: float = 8.0             # the feature's region: template vertices this close to its iBUG points
    x_scales: tuple = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2)
    y_scales: tuple = (1.0,)
    iters: int = 20                 # ICP iterations from each start
    stride: int = 1                 # every n-th vertex of the region takes part in the ICP
    keep: float = 0.9               # share of the points the trimmed ICP matches
    # The landing at the feature's own size (x and y scale 1) is the candidate; a landing at
    # another size replaces it when its RMS is at most ``width_ratio`` × that landing's. The
    # candidate is taken when its trimmed RMS is at most ``max_rms_ratio`` × the feature's own
    # where it stands (the RMS is flat within ~5 % of the right width, and in model its minimum
    # lies at 0.9-0.95x as often as at 1: taking the lowest would narrow features that were right).
    max_rms_ratio: float = 0.7
    width_ratio: float = 0.9
    max_angle: float = 10.0         # landings that turned the feature by more (degrees) are not candidates
    # The move is whole within ``move_margin`` mm of the feature's iBUG points and fades out over
    # ``fade`` mm beyond.
    move_margin: float = 2.0
    fade: float = 8.0


def face_axes(transform: np.ndarray):
    """((3,), (3,)): the face's x (across) and y (up) axes in the scan frame, unit and orthogonal,
    from the template-to-scan alignment ``transform`` (3, 4)."""
    lin = np.asarray(transform, float)[:, :3]
    x_axis = lin @ np.array([1.0, 0.0, 0.0])
    y_axis = lin @ np.array([0.0, 1.0, 0.0])
    x_axis /= np.linalg.norm(x_axis)
    y_axis -= (y_axis @ x_axis) * x_axis
    y_axis /= np.linalg.norm(y_axis)
    return x_axis, y_axis


def fit_feature(out: np.ndarray, template, scan, axes, ibug, extra, o: FeatureSearchOptions):
    """Fit one feature of the fitted template to the scan, moving ``out`` in place.

    Parameters
    ----------
    out : (N, 3) the fitted template, scan frame, mm; the feature's vertices are moved in place.
    template : the Template (rest vertices, iBUG-68 points).
    scan : Mesh (its :attr:`~facecorr.geometry.mesh.Mesh.surface`).
    axes : (x_axis, y_axis) of :func:`face_axes`.
    ibug : iBUG-68 indices of the feature; its region is the template vertices within ``o.margin``
        mm of them, its centre their mean.
    extra : (E, 3) or None, more points in the template's rest frame fitted with the region,
        carried by the region's affine map from rest to fitted shape (the eyeballs' fronts).
    o : FeatureSearchOptions (or a subclass).

    Returns
    -------
    dict or None (region too small, or every landing turned too far): ``x_scale``, ``y_scale``
    (the landing's start), ``rms_ratio`` (its trimmed RMS / the feature's own where it stands),
    ``angle_deg``, ``shift_mm`` (the centre's move) and ``moved``.
    """
    from ..geometry.icp import surface_icp
    from ..geometry.spatial import KDTree

    x_axis, y_axis = axes
    eye3 = np.eye(3)
    v0 = np.asarray(template.vertices, float)
    ib_ids = np.asarray(template.ibug68)[list(ibug)]
    ib_ids = ib_ids[ib_ids >= 0]
    dist, _ = KDTree(v0[ib_ids]).query(v0)
    dist = np.asarray(dist)
    ids = np.flatnonzero(dist <= float(o.margin))
    if len(ids) < 20:
        return None
    ids = ids[::max(1, int(o.stride))]
    region = out[ids]
    # the extra points ride with the region: the affine map of the region from the template's rest
    # shape to its fitted shape, applied to their rest positions
    a = np.c_[v0[ids], np.ones(len(ids))]
    m, *_ = np.linalg.lstsq(a, region, rcond=None)
    pts = region if extra is None or len(extra) == 0 else np.r_[region, np.c_[extra, np.ones(len(extra))] @ m]
    c = out[ib_ids].mean(axis=0)
    here = surface_icp(pts, scan.surface, [(eye3, np.zeros(3))], iters=0, keep=float(o.keep))[0][2]
    # every width (and height) a start of one ICP run: the start's linear part scales about the
    # feature's centre, the ICP's rigid steps compose onto it (scale first, then move)
    shapes = [(float(sx), float(sy), eye3 + (float(sx) - 1.0) * np.outer(x_axis, x_axis)
               + (float(sy) - 1.0) * np.outer(y_axis, y_axis)) for sx in o.x_scales for sy in o.y_scales]
    fits = surface_icp(pts, scan.surface, [(m3, c - m3 @ c) for _, _, m3 in shapes], iters=int(o.iters),
                       keep=float(o.keep))
    angles = []
    for (_, _, m3), f in zip(shapes, fits):
        rot = f[0] @ np.linalg.inv(m3)
        angles.append(float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0)))))
    ok = [k for k in range(len(fits)) if angles[k] <= float(o.max_angle)]
    if not ok:
        return None
    # the feature at its own size, refined where it fits; another size only when it fits clearly
    # better than that
    same = [k for k in ok if shapes[k][0] == 1.0 and shapes[k][1] == 1.0]
    k = same[0] if same else None
    ref = fits[k][2] if k is not None else here
    best = min(ok, key=lambda i: fits[i][2])
    if fits[best][2] <= float(o.width_ratio) * ref:
        k = best
    if k is None:
        return None
    lin_k, t, rms, _ = fits[k]
    sx, sy, _ = shapes[k]
    new_c = lin_k @ c + t
    e = dict(x_scale=sx, y_scale=sy, rms_ratio=float(rms / max(here, 1e-9)), angle_deg=angles[k],
             shift_mm=float(np.linalg.norm(new_c - c)), moved=False)
    if e["rms_ratio"] > float(o.max_rms_ratio):
        return e
    # every template vertex's position under the landing's map, taken in full near the feature and
    # faded out (a smooth step) over ``fade`` mm beyond
    w = np.clip(1.0 - (dist - float(o.move_margin)) / max(float(o.fade), 1e-9), 0.0, 1.0)
    w = w * w * (3.0 - 2.0 * w)
    near = np.flatnonzero(w > 0)
    q = out[near] @ lin_k.T + t
    out[near] += w[near, None] * (q - out[near])
    e["moved"] = True
    return e
