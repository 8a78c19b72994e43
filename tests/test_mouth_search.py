"""The mouth search (facecorr.registration.mouth): lips found where the model's fit left them off."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_face import make_scan  # noqa: E402

from facecorr.geometry.mesh import Mesh
from facecorr.registration import RegisterOptions, register
from facecorr.names import SUBNASAL
from facecorr.registration.mouth import MOUTH_IBUG, MouthSearchOptions, _move_weights, search_mouth
from facecorr.template import load_template


def _mouth_ids(tpl):
    ib = np.asarray(tpl.ibug68)[list(MOUTH_IBUG)]
    return ib[ib >= 0]


def test_lips_moved_off_are_brought_back_onto_the_scans_lips():
    """Scan = the template itself; the 'fitted' template has its mouth region 10 mm too high (a
    longer philtrum than the model's). The search puts the lips back within 1 mm and moves nothing
    above the subnasal (the nose) nor beyond its fading region."""
    tpl = load_template()
    scan = Mesh(np.asarray(tpl.vertices, float), np.asarray(tpl.faces))
    v = np.asarray(tpl.vertices, float)
    mouth = _mouth_ids(tpl)
    centre = v[mouth].mean(axis=0)
    w = np.clip(1.0 - (np.linalg.norm(v - centre, axis=1) - 22.0) / 20.0, 0.0, 1.0)
    off = v + w[:, None] * np.array([0.0, 10.0, 0.0])
    out, info = search_mouth(off, tpl, scan, np.hstack([np.eye(3), np.zeros((3, 1))]), MouthSearchOptions())
    assert info["moved"] and 8.0 < info["shift_mm"] < 12.0, info
    assert np.linalg.norm(out[mouth] - v[mouth], axis=1).mean() < 1.0
    still = (_move_weights(tpl, MouthSearchOptions().fade) == 0.0) | (v[:, 1] >= v[tpl.landmark_ids[SUBNASAL], 1])
    assert still.sum() > tpl.n_vertices // 2
    np.testing.assert_array_equal(out[still], off[still])


def test_lips_in_place_are_left_bitwise_alone():
    tpl = load_template()
    v = np.asarray(tpl.vertices, float)
    scan = Mesh(v.copy(), np.asarray(tpl.faces))
    out, info = search_mouth(v, tpl, scan, np.hstack([np.eye(3), np.zeros((3, 1))]), MouthSearchOptions())
    assert not info["moved"] and info["shift_mm"] < 1.0, info
    assert out is v


def _long_philtrum(shift):
    """A model-frame warp: everything from 8 mm under the subnasal (iBUG 33) down moves down by
    ``shift`` mm, faded in between 2 and 8 mm under it: a longer philtrum, the lips unchanged."""
    def warp(v):
        from facecorr.template import ICT_MODEL_PATH

        lm = np.load(ICT_MODEL_PATH)["landmarks68"]
        y0 = v[lm[33], 1]  # iBUG 33, the subnasal
        s = np.clip((y0 - 2.0 - v[:, 1]) / 6.0, 0.0, 1.0)
        out = v.copy()
        out[:, 1] -= shift * s * s * (3.0 - 2.0 * s)
        return out
    return warp


def test_register_finds_the_mouth_of_a_face_with_a_long_philtrum():
    """A face whose mouth and chin sit 14 mm lower than the model puts them: given the true
    landmarks, the model's fit leaves the lips high and the shape fit keeps them there. The search
    with a landing taken at 0.7× the lips' RMS brings them down (measured: lips 6.94 mm off
    without it, 3.90 mm with it). The default takes only landings at 0.55× (this one is 0.65×):
    on 3 of the 350 in-model test scans (sad faces) landings at 0.62-0.68× were wrong ones."""
    tpl = load_template()
    mesh, lms, gt, _ = make_scan(3, expression={"mouthSmile_L": 0.2}, warp=_long_philtrum(14.0))
    lips = _mouth_ids(tpl)

    def lip_error(search):
        res = register(mesh, lms, template=tpl, options=replace(RegisterOptions(), mouth_search=search))
        return np.linalg.norm(res.vertices[lips] - gt[lips], axis=1).mean(), res

    e_off, _ = lip_error(None)
    e_on, res = lip_error(MouthSearchOptions(max_rms_ratio=0.7))
    assert res.details["mouth_search"]["moved"]
    assert e_off > 6.0, (e_on, e_off)
    assert e_on < 0.75 * e_off, (e_on, e_off)
    e_default, res = lip_error(MouthSearchOptions())
    assert not res.details["mouth_search"]["moved"] and abs(e_default - e_off) < 1e-6


def test_a_face_of_the_model_is_left_as_it_was():
    """Lips where the model's fit puts them: the search changes nothing (two registrations of
    one scan agree to ~1e-8 mm, not bitwise: the threads' sums)."""
    tpl = load_template()
    mesh, lms, _, _ = make_scan(0)
    on = register(mesh, lms, template=tpl)
    off = register(mesh, lms, template=tpl, options=replace(RegisterOptions(), mouth_search=None))
    assert not on.details["mouth_search"]["moved"]
    np.testing.assert_allclose(on.vertices, off.vertices, rtol=0, atol=1e-6)


def test_a_moved_mouth_is_flagged_in_the_result():
    from facecorr.pipeline.correspond import CorrespondOptions, correspond

    mesh, lms, _, _ = make_scan(3, expression={"mouthSmile_L": 0.2}, warp=_long_philtrum(14.0))
    opts = CorrespondOptions(register=RegisterOptions(mouth_search=MouthSearchOptions(max_rms_ratio=0.7)), neutral=None)
    res = correspond(mesh, landmarks=lms, options=opts)
    moved = [f for f in res.flags if f.startswith("mouth_moved:")]
    assert len(moved) == 1 and 3.0 <= float(moved[0].split(":")[1].split("mm")[0]) <= 15.0, res.flags
    plain = correspond(mesh, landmarks=lms, options=CorrespondOptions(neutral=None))
    assert not any(f.startswith("mouth_moved:") for f in plain.flags)
