"""Beards: find the rough layer over the lower face, so that the registration can leave it out.

A full beard is a 3-10 mm layer over the chin, the cheeks and the upper lip; the registration
fits the template onto its outer surface, 3-10 mm in front of the skin the ground truth (and a
user) means (``ood_test``: the 21 full-beard scans' dense error 5.8 mm against 3.1 on the
others). What tells a beard from skin on the geometry alone is its roughness: hair scans as a
layer whose vertices jump ~0.5-1 mm along the normal independently, where skin shows only the
sensor's noise. :func:`rough_lower_face` measures the roughness
(:func:`facecorr.geometry.roughness.surface_roughness`) against the scan's own upper face, keeps
the rough vertices that lie under the fitted template's lower face (the lips, the nostrils and
the mouth corners, whose creases look rough too, are left out), and says whether they cover
enough of it to be a beard. :func:`register_under_beard` then redoes the shape fit on the scan
without them (:func:`facecorr.pipeline.correspond` calls it): over the beard the template keeps
the expression and identity fit's shape and the shape fit's smoothness instead of following the
hair's every bump (the expression fit itself still sees the beard; redoing it too is an option,
off by default, see :class:`BeardOptions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.roughness import smooth_over, surface_roughness, vertex_adjacency
from ..geometry.spatial import KDTree


@dataclass(frozen=True)
class BeardOptions:
    """Settings of :func:`rough_lower_face` (lengths in mm)."""

    radius: float = 2.5          # roughness averaged over this radius
    # A vertex is rough at this many times the median roughness of the scan's upper face (its own
    # sensor noise), and at least ``min_roughness``.
    ratio: float = 2.0
    min_roughness: float = 0.2
    # The rough vertices count as a beard when they are this share of the scan's lower face.
    min_share: float = 0.25
    # Rough vertices are grown by this much (the beard's edge is less rough than its middle).
    grow: float = 2.0
    # Scan vertices farther than this from the fitted template are not the face's.
    max_distance: float = 12.0
    # Also try the whole registration (expression and identity fit too) without the beard, kept
    # unless more than ``max_front_share`` of its lower face over the beard stands ``front_mm``
    # in front of the beard's surface or the model explains it worse; otherwise only the shape fit
    # is redone. Off: on `ood_test` it won big on some beards (dense 7.4 -> 5.6 mm) but, with the
    # chin gone, lost the jaw on others (mouth 6 -> 20 mm; BENCHMARKS.md, "Out of model,
    # fourteenth pass").
    whole_registration: bool = False
    front_mm: float = 1.0
    max_front_share: float = 0.05


def lower_face_zone(template) -> np.ndarray:
    """(N,) bool: template vertices where a beard grows, less the lips and the nose.

    In the template's rest frame (x across, y up, mm): below the nose tip, less the nose's base
    (within 20 mm of the midline above 3 mm under the subnasal point, and 6 mm around the
    subalare and subnasal points) and the lips (the ellipse
    through the lip contour, iBUG-68 points 48-59, grown by 3 mm).
    """
    v = np.asarray(template.vertices, dtype=np.float64)
    ids = dict(zip(("tip", "subnasal"), np.asarray(template.landmark_ids)[[6, 7]]))
    y_tip, y_sn = v[ids["tip"], 1], v[ids["subnasal"], 1]
    zone = v[:, 1] < y_tip
    zone &= ~((np.abs(v[:, 0]) < 20.0) & (v[:, 1] > y_sn - 3.0))
    nose_base = v[np.asarray(template.landmark_ids)[[4, 5, 7]]]  # subalare, subnasal
    zone &= np.min(np.linalg.norm(v[:, None, :] - nose_base[None], axis=2), axis=1) > 6.0
    lips = v[np.asarray(template.ibug68)[48:60]]
    c = lips.mean(axis=0)
    hw = 0.5 * np.ptp(lips[:, 0]) + 3.0
    hh = 0.5 * np.ptp(lips[:, 1]) + 3.0
    zone &= ((v[:, 0] - c[0]) / hw) ** 2 + ((v[:, 1] - c[1]) / hh) ** 2 > 1.0
    return zone


def upper_face_zone(template) -> np.ndarray:
    """(N,) bool: template vertices above the nose tip (the reference for the sensor's noise)."""
    v = np.asarray(template.vertices, dtype=np.float64)
    return v[:, 1] > v[np.asarray(template.landmark_ids)[6], 1] + 10.0


def rough_lower_face(scan, registered: np.ndarray, template, options: BeardOptions | None = None):
    """The scan's rough vertices over the fitted template's lower face.

    Parameters
    ----------
    scan : Mesh, mm.
    registered : (N, 3) the fitted template's vertices in the scan's frame, mm.
    template : the Template.
    options : BeardOptions.

    Returns
    -------
    (mask, info): (S,) bool over the scan's vertices (all False when no beard is found) and a
    dict with ``share`` (rough share of the scan's lower face), ``reference_mm`` (the upper
    face's median roughness), ``threshold_mm``, ``n_rough`` and ``beard`` (bool).
    """
    o = options or BeardOptions()
    n = scan.n_vertices
    none = np.zeros(n, dtype=bool)
    info = {"beard": False, "share": 0.0, "n_rough": 0}
    reg = np.asarray(registered, dtype=np.float64)
    # Only the scan around the fitted template matters (a raw crop's shoulders and clothing can be
    # most of it): the roughness is local (its averaging and the growing reach a few mm), so it is
    # computed on the scan inside the template's box grown by ``max_distance`` plus that reach.
    margin = o.max_distance + 4.0 * o.radius + 2.0 * o.grow
    sv = np.asarray(scan.vertices, dtype=np.float64)
    box = np.all((sv >= reg.min(axis=0) - margin) & (sv <= reg.max(axis=0) + margin), axis=1)
    idx = np.flatnonzero(box)
    if len(idx) < 100:
        return none, info
    e = np.asarray(scan.edges, dtype=np.int64)
    if len(idx) < 0.9 * n:  # else cutting the scan costs more than it saves
        local = np.full(n, -1, dtype=np.int64)
        local[idx] = np.arange(len(idx))
        e = local[e[box[e[:, 0]] & box[e[:, 1]]]]
    else:
        idx = np.arange(n)
    v = sv[idx]
    d, nearest = KDTree(reg).query(v)
    d, nearest = np.asarray(d), np.asarray(nearest)
    near = d <= o.max_distance
    in_lower = lower_face_zone(template)[nearest]
    lower = near & in_lower
    upper = near & upper_face_zone(template)[nearest]
    if lower.sum() < 50 or upper.sum() < 50:
        return none, info
    adj = vertex_adjacency(len(v), e)
    rough = surface_roughness(v, e, np.asarray(scan.vertex_normals)[idx], o.radius, adjacency=adj)
    ref = float(np.median(rough[upper]))
    thr = max(o.ratio * ref, o.min_roughness)
    flagged = lower & (rough > thr)
    share = float(flagged.sum() / lower.sum())
    info.update(share=share, reference_mm=ref, threshold_mm=thr, n_rough=int(flagged.sum()))
    if share < o.min_share:
        return none, info
    mean_edge = float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean())
    steps = int(np.clip(np.ceil(o.grow / max(mean_edge, 1e-6)), 0, 20))
    grown = smooth_over(adj, flagged.astype(np.float64), steps) > 0.0 if steps else flagged
    mask = none.copy()
    mask[idx] = grown & near & (in_lower | flagged)
    info.update(beard=True, n_rough=int(mask.sum()))
    return mask, info


def front_share(registered: np.ndarray, scan, rough: np.ndarray, template, front_mm: float) -> float:
    """Share of the fitted template's lower-face vertices over the rough scan vertices that stand
    more than ``front_mm`` in front of the scan's surface (the skin lies behind a beard, never in
    front of it)."""
    v = np.ascontiguousarray(registered, dtype=np.float64)
    _, nearest = scan.kdtree.query(v)
    over = lower_face_zone(template) & rough[np.asarray(nearest)]
    if not over.any():
        return 0.0
    _, _, q, _, qn, _ = scan.surface.closest(v[over], 1)
    signed = np.einsum("ij,ij->i", v[over] - q, qn)
    return float(np.mean(signed > front_mm))


def register_under_beard(scan, reg, landmarks: dict, template, reg_options, options: BeardOptions, score):
    """Register again without a beard's rough layer, if the scan has one.

    Parameters
    ----------
    scan : Mesh, mm (the whole scan).
    reg : RegistrationResult on ``scan`` (from :func:`.register.register`).
    landmarks : the landmarks ``reg`` was registered with (scan frame, mm).
    template, reg_options : as given to :func:`.register.register`.
    options : BeardOptions.
    score : callable RegistrationResult -> float, lower = better explained by the model.

    Returns
    -------
    (reg, info): the registration to keep and :func:`rough_lower_face`'s info, plus ``how``:
    ``"none"`` (no beard), ``"register"`` (the whole registration redone on the scan less the
    beard: kept when its template does not stand in front of the beard, share ≤
    ``max_front_share``, and the model explains it at least as well) or ``"shape"`` (only the shape
    fit redone without the beard, from ``reg``'s expression fit).
    """
    from .register import refit_shape, register

    rough, info = rough_lower_face(scan, reg.vertices, template, options)
    info["how"] = "none"
    if not info["beard"]:
        return reg, info
    kept, _ = scan.submesh(~rough)
    out = None
    if options.whole_registration:
        again = register(kept, landmarks, template=template, options=reg_options)
        info["front_share"] = front_share(again.vertices, scan, rough, template, options.front_mm)
        if info["front_share"] <= options.max_front_share and score(again) <= score(reg):
            out, info["how"] = again, "register"
    if out is None:
        out, info["how"] = refit_shape(reg, kept, landmarks, template=template, options=reg_options), "shape"
    # distances to what was scanned, the beard included
    out.scan_distance = np.asarray(scan.kdtree.query(out.vertices)[0], dtype=np.float64)
    out.mhd = float(out.scan_distance.mean())
    return out, info
