"""Long lower faces: the scan's chin goes on below the fitted template's, so stretch the template.

On faces whose lower face is 25-35 % longer than any face the model was learned from, the fitted
template lies on the scan but slid up: 2 mm at the nose tip, 8 at the subnasal point, 13 at the
lips and 25-36 mm at the chin, given the true landmarks too (BENCHMARKS.md, "Out of model, tenth
pass"). Closest-point matches from the template see only the surface under it, not how far the
scan goes on, and the 8 landmarks do not reach below the subnasal point.

What the scan says is where its chin ends. Along the face's midline, below the fitted template's
menton (iBUG-68 point 8), a chin the template reaches faces forward for a few millimetres more
and then turns under; a chin the template stopped short of faces forward for another 18-45 mm
(``ood_test``). :func:`chin_extent` measures that run of forward-facing scan;
:func:`register_long_lower_face` then stretches the shape fit's start along the face's vertical
axis below the subnasal point (nothing at the subnasal point, the whole amount at the chin),
runs the mouth search on it again and redoes the shape fit, kept when the run below the new
chin is at least ``min_gain`` mm shorter.

Opt-in (``CorrespondOptions(chin=ChinOptions())``; off by default). On ``ood_test`` it found all
of M0005's long lower faces (dense 14.6 / 13.9 / 8.6 / 8.3 / 7.0 -> 6.5 / 5.6 / 5.4 / 5.9 / 4.9
mm), but on the held-back subjects it fired on five faces the template already fitted (runs of
24-39 mm under a right chin: shoulders, a beard, glasses, a plain lower-resolution scan) and made
all five worse (BENCHMARKS.md, "Out of model, fifteenth pass"): the run's length alone does not
tell a chin the template stopped short of from a chin that goes on into a forward-facing neck,
and a stretched chin on such a neck passes the ``min_gain`` test by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..names import SUBNASAL


@dataclass(frozen=True)
class ChinOptions:
    """Settings of :func:`chin_extent` and :func:`register_long_lower_face` (mm)."""

    half_width: float = 10.0      # scan vertices within this of the midline (across the face)
    depth: tuple = (-25.0, 15.0)  # and within this of the template's chin along the forward axis
    bin: float = 3.0              # the run is measured in bins of this height
    reach: float = 60.0           # down to this far below the template's chin
    # A bin faces forward when its normals' mean cosine with the face's forward axis is above
    # this. At 0.3 the rounded bottom of a chin the template fits (cosines 0.5 -> 0.3 over
    # 6-9 mm) counted too: 11 of 98 ood_test scans and 1 of 21 in-model raw crops had runs of
    # 18-27 mm and a refit tried for nothing (~0.4 s); the long lower faces' runs stay at 0.6-1.0.
    min_forward: float = 0.5
    start_within: float = 12.0    # the run starts at most this far below the template's chin
    # A run this long means the template stopped short of the scan's chin (in model the runs
    # are 6-9 mm on 21 raw crops; on ood_test's long lower faces 18-45 mm); a run to ``reach``
    # is no chin edge at all (a neck or clothing facing forward): nothing is done.
    min_extent: float = 18.0
    # The stretch moves the template's chin this much less than the run (the run below a menton
    # that fits ends within a bin or two) ...
    baseline: float = 3.0
    max_stretch: float = 50.0
    # ... and is kept when the run below the new fit's chin is at least this much shorter.
    min_gain: float = 6.0


def _axes(transform: np.ndarray):
    """(right, up, forward) unit vectors of the template frame in the scan frame."""
    lin = np.asarray(transform, dtype=np.float64)[:, :3]
    return tuple(lin[:, k] / np.linalg.norm(lin[:, k]) for k in range(3))


def chin_vertex(template) -> int:
    """The template's menton (iBUG-68 point 8: the bottom of the chin's front, above its
    underside); without it, the lowest vertex within 8 mm of the midline (rest frame: y up)."""
    ib = np.asarray(template.ibug68)
    if len(ib) > 8 and ib[8] >= 0:
        return int(ib[8])
    v = np.asarray(template.vertices, dtype=np.float64)
    mid = np.flatnonzero(np.abs(v[:, 0]) < 8.0)
    return int(mid[np.argmin(v[mid, 1])])


def chin_extent(scan, vertices: np.ndarray, template, transform: np.ndarray, options: ChinOptions | None = None):
    """How far the scan goes on facing forward below the fitted template's chin, mm.

    Parameters
    ----------
    scan : Mesh, mm.
    vertices : (N, 3) the fitted template in the scan's frame, mm.
    template : the Template.
    transform : (3, 4) template-to-scan alignment (its linear part gives the face's axes).
    options : ChinOptions.

    Returns
    -------
    (extent, profile): the run's length below the template's chin in mm (a multiple of
    ``bin``; ``reach`` when it never ends) and the per-bin mean cosines (NaN where a bin has
    fewer than 3 scan vertices), bins from ``-2 bin`` to ``reach``. The run is the first one that
    starts at most ``start_within`` below the chin (a slid template's chin may stand on the lower
    lip, over the sulcus below it) and ends at the first bin that does not face forward or has
    no scan; a run that starts lower is the neck, not more chin.
    """
    o = options or ChinOptions()
    right, up, fwd = _axes(transform)
    c = np.asarray(vertices, dtype=np.float64)[chin_vertex(template)]
    rel = np.asarray(scan.vertices, dtype=np.float64) - c
    below = -(rel @ up)
    dep = rel @ fwd
    sel = (np.abs(rel @ right) < o.half_width) & (below > -2.0 * o.bin) & (below < o.reach) \
        & (dep > o.depth[0]) & (dep < o.depth[1])
    normals = np.asarray(scan.vertex_normals, dtype=np.float64)[sel]
    # the scan's normals may point inwards: orient them by the face as a whole
    face = np.abs(rel @ right) < 30.0
    if np.median(np.asarray(scan.vertex_normals)[face] @ fwd) < 0.0:
        normals = -normals
    cos, b = normals @ fwd, below[sel]
    starts = np.arange(-2.0 * o.bin, o.reach, o.bin)
    profile = np.full(len(starts), np.nan)
    for i, s in enumerate(starts):
        k = (b >= s) & (b < s + o.bin)
        if k.sum() >= 3:
            profile[i] = float(cos[k].mean())
    extent, running = 0.0, False
    for s, p in zip(starts, profile):
        forward = p > o.min_forward
        if not running:
            if s > o.start_within:
                break
            running = forward
        elif not forward:
            break  # under the chin (or a hole): the run ends here
        if running:
            extent = float(s + o.bin)
    return extent, profile


def stretch_lower_face(vertices: np.ndarray, template, transform: np.ndarray, amount: float) -> np.ndarray:
    """(N, 3) ``vertices`` (scan frame) moved down the face's vertical axis by ``amount`` mm times
    a ramp over the template's rest frame: 0 at and above the subnasal point, 1 at the chin."""
    _, up, _ = _axes(transform)
    v = np.asarray(template.vertices, dtype=np.float64)
    y_sn = v[np.asarray(template.landmark_ids)[SUBNASAL], 1]
    y_chin = v[:, 1].min()
    w = np.clip((y_sn - v[:, 1]) / max(y_sn - y_chin, 1e-9), 0.0, 1.0)
    return np.asarray(vertices, dtype=np.float64) - (float(amount) * w)[:, None] * up[None, :]


def register_long_lower_face(scan, reg, landmarks: dict, template, reg_options, options: ChinOptions):
    """Stretch the lower face and redo the shape fit when the scan's chin goes on below the fit's.

    Parameters
    ----------
    scan : Mesh, mm.
    reg : RegistrationResult on ``scan`` (with ``transform`` and ``shape_start``).
    landmarks : the landmarks ``reg`` was registered with (scan frame, mm).
    template, reg_options : as given to :func:`.register.register`.
    options : ChinOptions.

    Returns
    -------
    (reg, info): the registration to keep (``reg`` itself unless the stretch was kept; its
    ``shape_start`` is then the stretched start) and a dict with ``extent`` (mm), ``stretch``
    (mm, 0 when not tried), ``extent_after`` (mm, when tried) and ``kept`` (bool).
    """
    from .expression import rim_mask
    from .mouth import search_mouth
    from .register import refit_shape

    extent, _ = chin_extent(scan, reg.vertices, template, reg.transform, options)
    info = {"extent": extent, "stretch": 0.0, "kept": False}
    if extent < options.min_extent or extent >= options.reach:
        return reg, info
    amount = float(min(extent - options.baseline, options.max_stretch))
    start = stretch_lower_face(reg.shape_start, template, reg.transform, amount)
    if reg_options.mouth_search is not None:
        start, _ = search_mouth(start, template, scan, reg.transform, reg_options.mouth_search,
                                exclude=rim_mask(template, 1))
    again = refit_shape(replace(reg, shape_start=start), scan, landmarks, template=template, options=reg_options)
    after, _ = chin_extent(scan, again.vertices, template, again.transform, options)
    info.update(stretch=amount, extent_after=after)
    if after <= extent - options.min_gain:
        info["kept"] = True
        return again, info
    return reg, info
