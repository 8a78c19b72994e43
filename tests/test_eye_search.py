"""The eye search (facecorr.registration.eyes): eyes found where the model's fit left them too
wide or too narrow, and the eyeball domes it fits with them (facecorr.template.eye_caps)."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_face import make_scan  # noqa: E402

from facecorr.registration import RegisterOptions, register
from facecorr.registration.eyes import EYE_IBUG, EyeSearchOptions, search_eyes
from facecorr.registration.nose import NoseSearchOptions
from facecorr.template import eye_caps, load_template, template_from_arrays
from facecorr.template.model import _inside_polygon

IDENTITY = np.hstack([np.eye(3), np.zeros((3, 1))])


def _eye_ids(tpl, name):
    return np.asarray(tpl.ibug68)[list(EYE_IBUG[name])]


def _widen(v, tpl, factor):
    """``v`` with each eye's region scaled by ``factor`` along x about the eye's centre, fully
    within 10 mm of its iBUG points and faded out over the next 10 mm (model frame)."""
    out = v.copy()
    for name in EYE_IBUG:
        ids = _eye_ids(tpl, name)
        c = v[ids].mean(axis=0)
        d = np.linalg.norm(v[:, None, :] - v[ids][None], axis=2).min(axis=1)
        w = np.clip(1.0 - (d - 10.0) / 10.0, 0.0, 1.0)
        out[:, 0] += w * (factor - 1.0) * (v[:, 0] - c[0])
    return out


def test_eye_caps_fill_each_eye_hole_from_behind_the_lids():
    tpl = load_template()
    caps = eye_caps(tpl)
    v = np.asarray(tpl.vertices)
    assert set(caps) == {"right_eye", "left_eye"}
    for name, cap in caps.items():
        loop = v[np.asarray(tpl.boundary_loops[name])]
        assert len(cap) > 50
        assert _inside_polygon(cap[:, :2], loop[:, :2]).all()
        # a dome: its middle (the cornea) stands in front of its rim, a few mm in front of the lids' rim
        r = np.linalg.norm(cap[:, :2] - cap[:, :2].mean(axis=0), axis=1)
        assert cap[r < np.median(r), 2].mean() > cap[r > np.median(r), 2].mean()
        assert loop[:, 2].max() < cap[:, 2].max() < loop[:, 2].max() + 5.0
    # the two domes mirror each other (the model is symmetric)
    mirrored = caps["left_eye"] * np.array([-1.0, 1.0, 1.0])
    assert abs(len(caps["left_eye"]) - len(caps["right_eye"])) <= 5
    d = np.linalg.norm(caps["right_eye"][:, None] - mirrored[None], axis=2).min(axis=1)
    assert np.median(d) < 0.5


def test_eye_caps_are_empty_for_a_template_not_cut_from_the_model():
    with np.load(Path(__import__("facecorr").__file__).parent / "data" / "template.npz") as d:
        arrays = {k: d[k] for k in d.files}
    arrays["vertices"] = arrays["vertices"] + np.float32(5.0)
    assert eye_caps(template_from_arrays(arrays)) == {}


def test_inside_polygon_matches_a_square():
    sq = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    pts = np.array([[0.5, 0.5], [1.5, 0.5], [0.5, -0.1], [0.99, 0.99]])
    np.testing.assert_array_equal(_inside_polygon(pts, sq), [True, False, False, True])


@pytest.fixture(scope="module")
def face_with_eyeballs():
    """A model face (no pose, no noise) with its eyeballs, and the template's vertices on it."""
    mesh, _, gt, _ = make_scan(1, expression={}, noise=0.0, rotate=False, eyeballs=True)
    return mesh, gt


@pytest.mark.parametrize("factor", [1.2, 0.83])
def test_eyes_fitted_too_wide_or_narrow_are_brought_back(face_with_eyeballs, factor):
    """The 'fitted' template has its eyes 20 % wider (or narrower) than the scan's: the search
    puts the eye contours back within 0.7 mm (they start 1.3-2.5 mm off) and moves nothing more
    than 25 mm from an eye."""
    tpl = load_template()
    mesh, gt = face_with_eyeballs
    off = _widen(gt, tpl, factor)
    out, info = search_eyes(off, tpl, mesh, IDENTITY, EyeSearchOptions())
    for name in EYE_IBUG:
        ids = _eye_ids(tpl, name)
        before = np.linalg.norm(off[ids] - gt[ids], axis=1).mean()
        after = np.linalg.norm(out[ids] - gt[ids], axis=1).mean()
        assert info[name]["moved"], info
        assert before > 1.2 and after < 0.7, (name, before, after, info[name])
        assert (info[name]["x_scale"] - 1.0) * (factor - 1.0) < 0, info[name]  # the other way
    ids = np.concatenate([_eye_ids(tpl, n) for n in EYE_IBUG])
    far = np.linalg.norm(gt[:, None] - gt[ids][None], axis=2).min(axis=1) > 25.0
    np.testing.assert_array_equal(out[far], off[far])


def test_eyes_in_place_stay_in_place(face_with_eyeballs):
    """Eyes already where the scan's are: no other width is taken, and the refinement at their own
    width moves the contours by under 0.2 mm."""
    tpl = load_template()
    mesh, gt = face_with_eyeballs
    out, info = search_eyes(gt, tpl, mesh, IDENTITY, EyeSearchOptions())
    for name in EYE_IBUG:
        ids = _eye_ids(tpl, name)
        assert info[name]["x_scale"] == 1.0 and info[name]["shift_mm"] < 0.2, info
        assert np.linalg.norm(out[ids] - gt[ids], axis=1).max() < 0.2


@pytest.mark.parametrize("option,options_class", [("eye_search", EyeSearchOptions), ("nose_search", NoseSearchOptions)])
def test_register_with_a_search_off_is_the_search_never_taken(option, options_class):
    """``eye_search=None`` (``nose_search=None``) and a search whose landings are never good enough
    give the same fit."""
    tpl = load_template()
    mesh, lms, _, _ = make_scan(0)
    never = register(mesh, lms, template=tpl,
                     options=replace(RegisterOptions(), **{option: options_class(max_rms_ratio=0.0)}))
    off = register(mesh, lms, template=tpl, options=replace(RegisterOptions(), **{option: None}))
    assert option not in off.details and not any(e["moved"] for e in never.details[option].values())
    np.testing.assert_allclose(never.vertices, off.vertices, rtol=0, atol=1e-6)


@pytest.mark.parametrize("subject,expression,level,measured", [
    ("M0002", "HA", 4, "4.80 -> 1.37 mm: the right eye 6.2 mm away"),
    ("F0001", "SU", 4, "4.49 -> 2.69 mm: narrower eyes"),
])
def test_the_pipeline_finds_the_eyes_of_out_of_model_faces(subject, expression, level, measured):
    """Two scans of the out-of-model preset (``bu3dfe-ood``, seed 0: identities at 2-3 sigma,
    warps, eye widths changed by up to 20 %), fully automatic: without the search the template's
    lids stay where the face model put them, with it the eye contours come at least 30 % closer
    (measured: ``measured``)."""
    from facecorr.geometry.mesh import Mesh
    from facecorr.pipeline.correspond import CorrespondOptions, correspond
    from facecorr.synth.ood_preset import make_ood_scan

    tpl = load_template()
    scan, *_ = make_ood_scan(0, subject, expression, level)
    mesh = Mesh(scan.vertices, scan.faces)
    ids = np.asarray(tpl.ibug68)[36:48]

    def eye_error(search):
        opts = CorrespondOptions(neutral=None, register=replace(RegisterOptions(), eye_search=search))
        res = correspond(mesh, options=opts)
        return np.nanmean(np.linalg.norm(res.vertices[ids] - scan.ibug68[36:48], axis=1)), res

    e_off, _ = eye_error(None)
    e_on, res = eye_error(EyeSearchOptions())
    assert e_off > 3.0 and e_on < 0.7 * e_off, (e_on, e_off)
    assert any(f.startswith("eye_moved:") for f in res.flags), res.flags
