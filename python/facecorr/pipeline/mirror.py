"""A registration turned about the viewing axis, found by the scan's mirror symmetry and redone.

The start search ranks rigid poses of the template by how well they fit the scan; on unusual faces
in strong expressions (disgust, fear) the template's upper face can fit better turned by 20-80°
about the nose than upright, and every later stage keeps that roll (BENCHMARKS.md, "Out of model,
thirteenth pass"). The scan itself says where its midline is: a face is close to mirror-symmetric
about its midsagittal plane. So when the scan is clearly asymmetric about the registered
template's mid-plane, the plane it is most symmetric about is searched for
(:func:`facecorr.geometry.symmetry.symmetry_plane`), the registration's pose is turned onto it,
the landmarks are predicted again from that pose and the scan registered again; the new fit is
kept when the scan is clearly more symmetric about it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.symmetry import face_sample, mirror_asymmetry, symmetry_plane
from ..geometry.transforms import kabsch, rotation_between


@dataclass(frozen=True)
class MirrorOptions:
    """Settings of :func:`mirror_check` (lengths mm, angles degrees)."""

    # Scan vertices within this distance of the registered nose tip are reflected (≤ max_points).
    radius: float = 60.0
    max_points: int = 4000
    # The share of reflected points whose distance to the scan's surface counts (hair, holes, a crop's
    # uneven border leave some without a mirror image).
    keep: float = 0.8
    # The plane search runs only when the scan's asymmetry about the fit's mid-plane is above this.
    min_asymmetry: float = 1.5
    # ... and a plane is taken only if the scan is at most ``plane_gain`` times as asymmetric about
    # it, and it is turned at least ``min_angle`` from the fit's mid-plane or lies at least
    # ``min_offset`` from the registered nose tip.
    plane_gain: float = 0.7
    min_angle: float = 10.0
    min_offset: float = 3.0
    # The redone registration is kept if the scan's asymmetry about its mid-plane is at most
    # ``accept_gain`` times the first fit's.
    accept_gain: float = 0.7
    # A final fit the scan is more asymmetric about than this is flagged (``asymmetric_fit``): in
    # model the largest asymmetry is 0.80 mm (350 bu3dfe test scans); out of model the correct
    # fits reach 1.98 mm (raw crops with hair and shoulders) and the fits above 2.0 mm are gross
    # failures (2 of 98 `ood_test` and 3 of 42 `ood_holdout` scans; BENCHMARKS.md, "Out of
    # model, sixteenth pass").
    flag_asymmetry: float = 2.0


def fitted_pose(template_vertices, registered_vertices):
    """(R (3, 3), s, t (3,)): the similarity ``x -> s R x + t`` taking the template's vertices
    (template frame) onto the registered ones (scan frame), least squares."""
    return kabsch(template_vertices, registered_vertices, with_scale=True)


def _nose_tip_vertex(template) -> int:
    from ..names import LANDMARK_NAMES

    return int(np.asarray(template.landmark_ids)[LANDMARK_NAMES.index("nose_tip")])


def fit_asymmetry(work, reg, template, o: MirrorOptions):
    """(asymmetry mm, sample (m, 3), nose tip (3,), mid-plane normal (3,), (R, s, t)): the scan's
    :func:`mirror_asymmetry` about the mid-plane (the template's x = 0 plane) of registration
    ``reg``, through its registered nose tip."""
    r, s, t = fitted_pose(template.vertices, reg.vertices)
    tip = np.asarray(reg.landmarks_registered["nose_tip"], dtype=np.float64)
    normal = r[:, 0]
    sample = face_sample(work.vertices, tip, o.radius, o.max_points)
    return mirror_asymmetry(sample, work.surface, tip, normal, o.keep), sample, tip, normal, (r, s, t)


def mirror_check(work, reg, template, o: MirrorOptions, redo):
    """Check registration ``reg`` of scan ``work`` against the scan's mirror symmetry; redo it
    from a pose turned onto the scan's own symmetry plane when that plane is clearly better.

    ``redo(start_pose)`` predicts the landmarks from ``start_pose`` ((R, t, rms, size), see
    :func:`facecorr.landmarks.predict_landmarks`) and registers again, returning
    ``(registration, positions, confidence, flags)``. Returns ``(None, info)`` when nothing is
    changed, else ``(that tuple, info)``; ``info`` has the asymmetries (mm: ``asymmetry`` of the
    given fit, ``final`` of the one returned), the plane's turn (deg) and offset (mm).
    """
    a0, sample, tip, n0, (r, s, t) = fit_asymmetry(work, reg, template, o)
    info = dict(asymmetry=a0, final=a0)
    if not np.isfinite(a0) or a0 <= o.min_asymmetry:
        return None, info
    forward = r[:, 2]
    n1, c1, a1 = symmetry_plane(sample, work.surface, tip, n0, forward, keep=o.keep)
    turn = float(np.degrees(np.arccos(np.clip(abs(n0 @ n1), -1.0, 1.0))))
    offset = float((tip - c1) @ n1)
    info.update(plane_asymmetry=a1, turn_deg=turn, offset_mm=offset)
    if not (a1 <= o.plane_gain * a0 and (turn >= o.min_angle or abs(offset) >= o.min_offset)):
        return None, info
    # The new start: the fit's rotation turned (the least rotation) onto the plane, the template's
    # nose tip on the registered one moved onto the plane, at the template's own size (the wrong
    # fit's size is no guide: turned fits shrink to 0.4-0.7x); the landmark search's similarity
    # ICP then finds the face's size.
    rot = rotation_between(n0, n1) @ r
    tip_new = tip - offset * n1
    x_tip = np.asarray(template.vertices, dtype=np.float64)[_nose_tip_vertex(template)]
    pose = (rot, tip_new - rot @ x_tip, 0.0, 1.0)
    out = redo(pose)
    a2 = fit_asymmetry(work, out[0], template, o)[0]
    info.update(redone_asymmetry=a2)
    if a2 <= o.accept_gain * a0:
        info.update(final=a2)
        return out, info
    return None, info
