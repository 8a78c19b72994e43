"""Eye search: fit the template's eyes to the scan's eye fissures before the shape fit (issue 14).

Out of model the expression-and-identity fit places the template's eyes by the template's own
eye shape: on a face whose eyes are narrower or wider than any training face's the lids end
millimetres beside the scan's eye corners (``ood_test``: inner corners 6-7 mm off on a whole
subject), and the shape fit keeps them there. The template has a hole where the eye is, so its
closest-point matches never notice that the hole covers skin or that the lids cover the eyeball:
nothing pulls the lids across the surface. The scan shows the eyeball through the fissure. With
the front of an eyeball put into the template's hole (the ICT model's own eyeball,
:func:`facecorr.template.eye_caps`), the eye is a relief again: lids closing around a dome
whose cornea stands out, and a hole that may no longer lie over skin. A trimmed ICP of the eye's region with its dome, started at a ladder
of widths (a scale along the face's x axis about the eye's centre) and heights, lands where the
lids fit around the scan's eyeball; a landing clearly better than where the eye stands (trimmed
RMS ≤ ``max_rms_ratio`` × its own) moves the eye, faded out over ``fade`` mm around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: iBUG-68 indices of each eye's contour, by the template's eye-hole loop name.
EYE_IBUG = {"right_eye": tuple(range(36, 42)), "left_eye": tuple(range(42, 48))}


@dataclass(frozen=True)
class EyeSearchOptions:
    """Settings of :func:`search_eyes` (mm; scales are factors along the face's x / y axes)."""

    margin: float = 8.0             # the eye's region: template vertices this close to its iBUG points
    x_scales: tuple = (0.75, 0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2, 1.25)
    y_scales: tuple = (1.0,)
    iters: int = 20                 # ICP iterations from each start
    stride: int = 1                 # every n-th vertex of the region takes part in the ICP
    keep: float = 0.9               # share of the points the trimmed ICP matches
    # The landing at the eye's own width (x and y scale 1) is the candidate; a landing at another
    # width replaces it when its RMS is at most ``width_ratio`` × that landing's. The candidate is
    # taken when its trimmed RMS is at most ``max_rms_ratio`` × the eye's own where it stands: at
    # 0.7 no eye of 175 in-model test scans moves and 21 of 83 out-of-model scans' eyes improve by
    # > 0.2 mm (2 get worse); at 0.8 / 1.0 the in-model eyes lose 4 / 10 % (BENCHMARKS.md, "Out
    # of model, eleventh pass").
    max_rms_ratio: float = 0.7
    width_ratio: float = 0.9
    max_angle: float = 10.0         # landings that turned the eye by more (degrees) are not candidates
    # The move is whole within ``move_margin`` mm of the eye's iBUG points (the lids) and fades out
    # over ``fade`` mm beyond: moving the whole region (8 + 10 mm) dragged the brows and the cheeks
    # (out of model: brows 3.17 -> 3.22 mm, dense 3.61 -> 3.63 on the scans that register).
    move_margin: float = 2.0
    fade: float = 8.0


def _region(template, name: str, margin: float):
    """(ids (R,), dist (N,)): the template vertices within ``margin`` mm of the eye's iBUG points
    (the lids and the skin around them: the ICP's points), and every template vertex's distance to
    the nearest of those points (mm, template frame; the move's weights are a function of it)."""
    from ..geometry.spatial import KDTree

    v = np.asarray(template.vertices, float)
    ib = np.asarray(template.ibug68)[list(EYE_IBUG[name])]
    d, _ = KDTree(v[ib]).query(v)
    return np.flatnonzero(d <= margin), d


def search_eyes(vertices: np.ndarray, template, scan, transform: np.ndarray, options: EyeSearchOptions):
    """Where the scan's eyes are, for a fitted template whose eyes may be too wide or narrow.

    Parameters
    ----------
    vertices : (N, 3) the fitted template (expression fit), scan frame, mm.
    template : the Template (its eye-hole loops, iBUG-68 points; frame: x across, y up).
    scan : Mesh (its :attr:`~facecorr.geometry.mesh.Mesh.surface`).
    transform : (3, 4) the template-to-scan alignment (its linear part gives the face's axes).
    options : EyeSearchOptions.

    Returns
    -------
    (vertices (N, 3), info dict): the template with each eye's region moved where its lids fit
    the scan's eye (the input itself when no landing is clearly better), and per eye
    (``right_eye``, ``left_eye``) ``x_scale``, ``y_scale``, ``rms_ratio`` (best landing's trimmed
    RMS / the eye's own where it stands), ``angle_deg``, ``shift_mm`` (the eye centre's move) and
    ``moved``.
    """
    from ..geometry.icp import surface_icp
    from ..template import eye_caps

    o = options
    caps = eye_caps(template)
    out = np.asarray(vertices, float).copy()
    v0 = np.asarray(template.vertices, float)
    lin = np.asarray(transform, float)[:, :3]
    x_axis = lin @ np.array([1.0, 0.0, 0.0])
    y_axis = lin @ np.array([0.0, 1.0, 0.0])
    x_axis /= np.linalg.norm(x_axis)
    y_axis -= (y_axis @ x_axis) * x_axis
    y_axis /= np.linalg.norm(y_axis)
    info = {}
    eye3 = np.eye(3)
    for name in EYE_IBUG:
        cap = caps.get(name)
        if cap is None or len(cap) == 0:
            continue
        ids, dist = _region(template, name, float(o.margin))
        if len(ids) < 20:
            continue
        ids = ids[::max(1, int(o.stride))]
        region = out[ids]
        # the dome rides with the region: the affine map of the region from the template's rest
        # shape to its fitted shape, applied to the dome's rest points
        a = np.c_[v0[ids], np.ones(len(ids))]
        m, *_ = np.linalg.lstsq(a, region, rcond=None)
        pts = np.r_[region, np.c_[cap, np.ones(len(cap))] @ m]
        c = out[np.asarray(template.ibug68)[list(EYE_IBUG[name])]].mean(axis=0)
        here = surface_icp(pts, scan.surface, [(eye3, np.zeros(3))], iters=0, keep=float(o.keep))[0][2]
        # every width (and height) a start of one ICP run: the start's linear part scales about the
        # eye's centre, the ICP's rigid steps compose onto it (scale first, then move)
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
            continue
        # the eye at its own width, refined where it fits; another width only when it fits clearly
        # better than that (the RMS is flat within ~5 % of the right width, and in model its
        # minimum lies at 0.9-0.95x as often as at 1: taking it would narrow eyes that were right)
        same = [k for k in ok if shapes[k][0] == 1.0 and shapes[k][1] == 1.0]
        k = same[0] if same else None
        ref = fits[k][2] if k is not None else here
        best = min(ok, key=lambda i: fits[i][2])
        if fits[best][2] <= float(o.width_ratio) * ref:
            k = best
        if k is None:
            continue
        lin_k, t, rms, _ = fits[k]
        sx, sy, _ = shapes[k]
        new_c = lin_k @ c + t
        e = dict(x_scale=sx, y_scale=sy, rms_ratio=float(rms / max(here, 1e-9)), angle_deg=angles[k],
                 shift_mm=float(np.linalg.norm(new_c - c)), moved=False)
        info[name] = e
        if e["rms_ratio"] > float(o.max_rms_ratio):
            continue
        # every template vertex's position under the landing's map, taken in full near the eye and
        # faded out (a smooth step) over ``fade`` mm beyond
        w = np.clip(1.0 - (dist - float(o.move_margin)) / max(float(o.fade), 1e-9), 0.0, 1.0)
        w = w * w * (3.0 - 2.0 * w)
        near = np.flatnonzero(w > 0)
        q = out[near] @ lin_k.T + t
        out[near] += w[near, None] * (q - out[near])
        e["moved"] = True
    return out, info
