"""Long lower faces (facecorr.registration.chin, opt-in: ``CorrespondOptions(chin=ChinOptions())``):
a scan whose chin goes on below the fitted template's gets the template's lower face stretched,
and only then."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_face import _model, make_scan  # noqa: E402

from facecorr.names import SUBNASAL  # noqa: E402
from facecorr.pipeline import correspond  # noqa: E402
from facecorr.pipeline.correspond import CorrespondOptions  # noqa: E402
from facecorr.registration.chin import ChinOptions, chin_extent, chin_vertex, stretch_lower_face  # noqa: E402
from facecorr.template import load_template  # noqa: E402


def similarity(src, dst):
    """(3, 4) s R x + t taking src (N, 3) onto dst (N, 3) in the least-squares sense."""
    cs, cd = src.mean(0), dst.mean(0)
    a, b = src - cs, dst - cd
    u, s, vt = np.linalg.svd(b.T @ a)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    scale = np.trace(np.diag(s) @ d) / (a ** 2).sum()
    return np.hstack([scale * r, (cd - scale * r @ cs)[:, None]])


def longer_lower_face(factor):
    """A warp of the model's vertices (model frame, y up): everything below the subnasal point
    (iBUG 33) stretched ``factor`` times along y: a lower face longer than the model can make."""
    def warp(v):
        sn = v[_model()["landmarks68"][33], 1]
        v = v.copy()
        below = v[:, 1] < sn
        v[below, 1] = sn - factor * (sn - v[below, 1])
        return v
    return warp


def test_the_stretch_leaves_the_nose_and_moves_the_chin_down_the_face():
    t = load_template()
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    q *= np.sign(np.linalg.det(q))
    transform = np.hstack([1.1 * q, rng.uniform(-50, 50, (3, 1))])
    v = np.asarray(t.vertices) @ transform[:, :3].T + transform[:, 3]
    out = stretch_lower_face(v, t, transform, 20.0)
    rest = np.asarray(t.vertices)
    above = rest[:, 1] >= rest[t.landmark_ids[SUBNASAL], 1]
    assert np.array_equal(out[above], v[above])
    up = q[:, 1]
    move = out - v
    # every move is along the face's vertical axis, downwards, at most the amount: 20 at the chin
    assert np.allclose(move - np.outer(move @ up, up), 0.0, atol=1e-9)
    assert np.all(move @ up <= 1e-9) and np.all(move @ up >= -20.0 - 1e-9)
    assert move[np.argmin(rest[:, 1])] @ up == pytest.approx(-20.0)
    assert -20.0 < move[chin_vertex(t)] @ up < -10.0  # the menton, above the chin's underside


@pytest.fixture(scope="module")
def long_face():
    return make_scan(3, expression={"jawOpen": 0.1}, noise=0.1, rotate=False, warp=longer_lower_face(1.7))


@pytest.fixture(scope="module")
def usual_face():
    return make_scan(3, expression={"jawOpen": 0.1}, noise=0.1, rotate=False)


def test_the_chin_ends_under_a_template_that_fits(usual_face, long_face):
    t = load_template()
    for mesh, _, gt, _ in (usual_face, long_face):
        # the template placed where it belongs: no forward-facing run below its chin (the usual
        # face's under-chin faces down; the long face's scan is cropped there)
        extent, profile = chin_extent(mesh, gt, t, similarity(np.asarray(t.vertices), gt))
        assert extent < ChinOptions().min_extent
    # on the usual face the profile reads the chin's front, then its underside
    profile = chin_extent(usual_face[0], usual_face[2], t, similarity(np.asarray(t.vertices), usual_face[2]))[1]
    seen = profile[np.isfinite(profile)]
    assert len(seen) >= 3 and seen[0] > 0.5 and seen[-1] < 0.3


def test_a_long_lower_face_is_stretched_onto_the_scan(long_face):
    mesh, lms, gt, _ = long_face
    t = load_template()
    rest = np.asarray(t.vertices)
    lower = rest[:, 1] < rest[t.landmark_ids[SUBNASAL], 1]
    on = correspond(mesh, landmarks=lms, options=replace(CorrespondOptions(), chin=ChinOptions()))
    off = correspond(mesh, landmarks=lms)
    err_on, err_off = (np.linalg.norm(r.vertices - gt, axis=1) for r in (on, off))
    assert any(f.startswith("long_lower_face:") for f in on.flags)
    assert not any(f.startswith("long_lower_face:") for f in off.flags)
    # measured: lower face 11.7 -> 3.0 mm, the rest unchanged
    assert err_on[lower].mean() < 0.4 * err_off[lower].mean()
    assert err_on[~lower].mean() <= err_off[~lower].mean() + 0.1


def test_a_usual_face_is_left_alone(usual_face):
    mesh, lms, _, _ = usual_face
    on = correspond(mesh, landmarks=lms, options=replace(CorrespondOptions(), chin=ChinOptions()))
    off = correspond(mesh, landmarks=lms)
    assert not any(f.startswith("long_lower_face:") for f in on.flags)
    # the same registration (bitwise with one thread; with several the sums' order moves ~1e-8 mm)
    assert np.abs(on.vertices - off.vertices).max() < 1e-6
