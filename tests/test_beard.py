"""Beards (facecorr.registration.beard): the rough layer over the lower face is found, and the
registration leaves it out of the shape fit."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_face import make_scan  # noqa: E402

from facecorr.geometry.mesh import Mesh  # noqa: E402
from facecorr.geometry.spatial import KDTree  # noqa: E402
from facecorr.pipeline import correspond  # noqa: E402
from facecorr.pipeline.correspond import CorrespondOptions  # noqa: E402
from facecorr.registration.beard import BeardOptions, lower_face_zone, rough_lower_face  # noqa: E402
from facecorr.template import load_template  # noqa: E402


def add_beard(mesh, landmarks, thickness=6.0, seed=0):
    """(scan with a full beard, (S,) bool lifted vertices): the scan's vertices under the nose and
    on the lower cheeks, less the lips, lifted along their normals by ``thickness`` mm plus
    half-normal noise of 1 mm (a beard as a range scanner sees it). The scan is in the model's
    frame (x across, y up)."""
    v = mesh.vertices.copy()
    sn, tip = landmarks["subnasal"], landmarks["nose_tip"]
    sub_l, sub_r = landmarks["left_subalare"], landmarks["right_subalare"]
    mid_x = 0.5 * (sub_l[0] + sub_r[0])
    side = np.abs(v[:, 0] - mid_x) > 28.0
    zone = ((v[:, 1] < sn[1] - 3.0) | (side & (v[:, 1] < tip[1]))) & (v[:, 2] > tip[2] - 90.0)
    zone &= np.linalg.norm(v - sn, axis=1) < 95.0
    # the lips stay free: an ellipse around the mouth, under the subnasal point
    mouth_c = np.array([mid_x, sn[1] - 17.0])
    zone &= ((v[:, 0] - mouth_c[0]) / 30.0) ** 2 + ((v[:, 1] - mouth_c[1]) / 13.0) ** 2 > 1.0
    rng = np.random.default_rng(seed)
    lift = thickness + np.abs(rng.normal(0.0, 1.0, len(v)))
    v[zone] += lift[zone, None] * mesh.vertex_normals[zone]
    return Mesh(v, mesh.faces), zone


@pytest.fixture(scope="module")
def scans():
    mesh, lms, gt, _ = make_scan(5, expression={"mouthSmile_L": 0.3, "mouthSmile_R": 0.3}, rotate=False, noise=0.15)
    bearded, lifted = add_beard(mesh, lms)
    return mesh, bearded, lifted, lms, gt


def test_the_beard_is_found_and_the_lips_are_not(scans):
    mesh, bearded, lifted, lms, gt = scans
    t = load_template()
    mask, info = rough_lower_face(bearded, gt, t)
    assert info["beard"] and info["share"] > 0.4
    # every lifted vertex over the template's lower face is found; the others flagged are the
    # beard's edge (the step onto the skin is rough too, and the mask is grown by 2 mm)
    d, nearest = KDTree(gt).query(bearded.vertices)
    over = lower_face_zone(t)[np.asarray(nearest)] & (np.asarray(d) < 12.0)
    assert (mask & lifted & over).sum() >= 0.9 * (lifted & over).sum()
    assert (mask & ~lifted).sum() <= 0.25 * mask.sum()
    # the lips and the nose are never cut: no flagged vertex near the mouth's or the nose's points
    for name in ("subnasal", "nose_tip", "left_subalare", "right_subalare"):
        assert np.linalg.norm(bearded.vertices[mask] - lms[name], axis=1).min() > 3.0
    clean_mask, clean = rough_lower_face(mesh, gt, t)
    assert not clean["beard"] and not clean_mask.any()
    assert clean["share"] < 0.1


def test_the_zone_leaves_out_lips_and_nose():
    t = load_template()
    zone = lower_face_zone(t)
    ibug = np.asarray(t.ibug68)
    assert not zone[ibug[48:68]].any()          # lips
    assert not zone[ibug[30:36]].any()          # nose tip, nostrils
    assert zone[ibug[[6, 7, 8, 9, 10]]].all()   # the chin's contour points


def test_the_registration_goes_under_the_beard(scans):
    _, bearded, lifted, lms, gt = scans
    t = load_template()
    zone = lower_face_zone(t)
    on = correspond(bearded, landmarks=lms, template=t)
    off = correspond(bearded, landmarks=lms, template=t, options=replace(CorrespondOptions(), beard=None))
    err_on = np.linalg.norm(on.vertices - gt, axis=1)
    err_off = np.linalg.norm(off.vertices - gt, axis=1)
    assert any(f.startswith("beard:") for f in on.flags)
    assert not any(f.startswith("beard:") for f in off.flags)
    # the lower face is fitted to the skin, not to the hair 6-7 mm in front of it
    assert err_off[zone].mean() > 4.0
    assert err_on[zone].mean() < 0.8 * err_off[zone].mean()
    # and the rest of the face is no worse
    assert err_on[~zone].mean() < err_off[~zone].mean() + 0.1


def test_a_whole_registration_without_the_chin_is_refused_when_it_misfits(scans):
    # Without its lower face this scan's expression fit loses the jaw (lower face ~19 mm off,
    # fit RMS up): the whole redone registration must be refused and the shape fit redone instead.
    _, bearded, _, lms, gt = scans
    t = load_template()
    whole = correspond(bearded, landmarks=lms, template=t,
                       options=replace(CorrespondOptions(), beard=BeardOptions(whole_registration=True)))
    shape = correspond(bearded, landmarks=lms, template=t)
    assert any(f.startswith("beard:") and f.endswith("left out of the shape fit") for f in whole.flags)
    assert np.abs(whole.vertices - shape.vertices).max() < 1e-4  # mm (threaded sums: not bitwise)
