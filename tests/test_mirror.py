"""Mirror symmetry (facecorr.geometry.symmetry) and the check that turns a registration whose
midline is off the scan's symmetry plane (facecorr.pipeline.mirror)."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_face import make_scan  # noqa: E402

from facecorr.geometry.closest import closest_points_on_triangles  # noqa: E402
from facecorr.geometry.mesh import Mesh  # noqa: E402
from facecorr.geometry.symmetry import face_sample, mirror_asymmetry, symmetry_plane  # noqa: E402
from facecorr.geometry.transforms import axis_angle, kabsch  # noqa: E402
from facecorr.names import LANDMARK_NAMES  # noqa: E402
from facecorr.pipeline.mirror import MirrorOptions, mirror_check  # noqa: E402
from facecorr.template import load_template  # noqa: E402


def rotation(axis, deg):
    return axis_angle(axis, np.radians(deg))


@pytest.fixture(scope="module")
def template():
    return load_template()


@pytest.fixture(scope="module")
def template_scan(template):
    """The template itself as a scan (mirror-symmetric about x = 0)."""
    return Mesh(np.asarray(template.vertices, float), np.asarray(template.faces))


def reference_asymmetry(vertices, faces, sample, centre, normal, keep):
    """The same measure by brute force: an explicit reflection matrix, and each reflected point's
    distance to every triangle of the mesh (numpy), the least of them."""
    n = normal / np.linalg.norm(normal)
    h = np.eye(3) - 2.0 * np.outer(n, n)
    refl = (sample - centre) @ h.T + centre
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    d = np.array([closest_points_on_triangles(np.broadcast_to(p, a.shape), a, b, c)[1].min() for p in refl])
    d = np.sort(d)[: max(1, int(keep * len(d)))]
    return np.sqrt(np.mean(d ** 2))


@settings(max_examples=8, deadline=None)
@given(st.floats(-90, 90), st.floats(0.5, 1.0))
def test_asymmetry_matches_a_brute_force_reference(template_scan, deg, keep):
    pts = template_scan.vertices
    tip = pts[np.argmax(pts[:, 2])]
    n = rotation([0, 0, 1], deg) @ np.array([1.0, 0, 0])
    sample = face_sample(pts, tip, 60.0, 60)
    got = mirror_asymmetry(sample, template_scan.surface, tip, n, keep)
    want = reference_asymmetry(pts, template_scan.faces, sample, tip, n, keep)
    # the surface's closest point is searched locally (around the nearest vertex, then a walk): a
    # real surface point, so never nearer than the global one; a mirror image far off the surface
    # (the plane turned 20-90 deg) can get a farther one, which moves the trimmed RMS by a few %
    assert want - 1e-9 <= got <= 1.1 * want + 1e-9


def test_asymmetry_is_zero_about_the_midline_only(template_scan):
    pts = template_scan.vertices
    tip = pts[np.argmax(pts[:, 2])]
    sample = face_sample(pts, tip, 60.0, 4000)
    a = [mirror_asymmetry(sample, template_scan.surface, tip, rotation([0, 0, 1], d) @ [1.0, 0, 0], 0.8)
         for d in (0, 20, 45, 80)]
    assert a[0] < 0.05  # the template is symmetric (vertex spacing ~2 mm: mirror images land on vertices)
    assert min(a[1:]) > 1.0  # 3-5 mm about a plane turned 20-80 deg


@pytest.mark.parametrize("deg", [25.0, -50.0, 80.0])
def test_symmetry_plane_found_from_a_turned_start(template_scan, deg):
    pts = template_scan.vertices
    tip = pts[np.argmax(pts[:, 2])]
    start = rotation([0, 0, 1], deg) @ np.array([1.0, 0, 0])
    sample = face_sample(pts, tip, 60.0, 4000)
    n, c, a = symmetry_plane(sample, template_scan.surface, tip, start, [0, 0, 1.0])
    assert abs(n[0]) > np.cos(np.radians(0.5))  # within 0.5 deg of the x axis
    assert abs(c[0]) < 0.5 and a < 0.1
    assert n @ start >= 0.0  # the sign follows the start


def fake_registration(template, vertices):
    ids = np.asarray(template.landmark_ids)
    return SimpleNamespace(vertices=vertices, landmarks_registered={n: vertices[i] for n, i in zip(LANDMARK_NAMES, ids)})


def test_a_rolled_registration_is_turned_back(template):
    """A scan of a face in some pose; the 'registration' is the template placed on it turned 60 deg
    about the forward axis. The check must hand ``redo`` a pose within a few degrees of the
    truth, and keep the redone fit only because it is more symmetric."""
    scan, landmarks, gt, _ = make_scan(seed=3, noise=0.05)
    r_true = kabsch(np.asarray(template.vertices), gt)[0]
    tip = landmarks["nose_tip"]
    q = rotation(r_true[:, 2], 60.0)
    rolled = (gt - tip) @ q.T + tip
    calls = []

    def redo(pose):
        calls.append(pose)
        return fake_registration(template, gt), {}, {}, []

    out, info = mirror_check(scan, fake_registration(template, rolled), template, MirrorOptions(), redo)
    assert len(calls) == 1 and out is not None
    r, t, _, s = calls[0]
    err = np.degrees(np.arccos(np.clip((np.trace(r.T @ r_true) - 1) / 2, -1, 1)))
    assert err < 5.0, err
    assert s == 1.0  # the template's own size: the landmark search's similarity ICP finds the face's
    x_tip = np.asarray(template.vertices)[np.asarray(template.landmark_ids)[LANDMARK_NAMES.index("nose_tip")]]
    assert np.linalg.norm(r @ x_tip + t - tip) < 3.0  # the template's nose tip on the scan's
    assert info["redone_asymmetry"] < 0.7 * info["asymmetry"]
    assert 50.0 < info["turn_deg"] < 70.0


def test_an_upright_registration_is_left_alone(template):
    scan, _, gt, _ = make_scan(seed=4, noise=0.05)
    out, info = mirror_check(scan, fake_registration(template, gt), template, MirrorOptions(),
                             lambda pose: pytest.fail("redo must not run"))
    assert out is None and info["asymmetry"] < MirrorOptions().min_asymmetry


def test_a_redone_fit_that_is_no_more_symmetric_is_dropped(template):
    scan, landmarks, gt, _ = make_scan(seed=5, noise=0.05)
    r_true = kabsch(np.asarray(template.vertices), gt)[0]
    tip = landmarks["nose_tip"]
    rolled = (gt - tip) @ rotation(r_true[:, 2], 60.0).T + tip
    out, info = mirror_check(scan, fake_registration(template, rolled), template, MirrorOptions(),
                             lambda pose: (fake_registration(template, rolled), {}, {}, []))
    assert out is None and info["redone_asymmetry"] == pytest.approx(info["asymmetry"])


@pytest.mark.parametrize("mirror", [True, False])
def test_correspond_turns_a_wrong_pose_back(monkeypatch, template, mirror):
    """Every landmark search answers with the landmarks turned 35 deg about the nose (a wrong pose
    no refit repairs); a prediction from a given start pose is the real one. The mirror check
    finds the turn and registers the scan again from the turned-back pose; without it the wrong
    fit stays."""
    import facecorr.landmarks as lm_pkg
    from dataclasses import replace as dc_replace

    from facecorr.landmarks.predict import LandmarkResult
    from facecorr.pipeline import CorrespondOptions, correspond
    from test_registration import _turned_about_the_nose

    real_predict = lm_pkg.predict_landmarks
    mesh, lms, gt, _ = make_scan(3)
    starts = []

    def fake_predict(mesh_, model=None, options=None, start_pose=None):
        if start_pose is not None:
            starts.append(start_pose)
            return real_predict(mesh_, model=model, options=options, start_pose=start_pose)
        shift = mesh_.vertices[0] - mesh.vertices[0]  # correspond predicts on the scan centred on the origin
        pos = {k: np.asarray(v) + shift for k, v in _turned_about_the_nose(lms, 35.0).items()}
        return LandmarkResult(positions=pos, confidence={n: 0.9 for n in LANDMARK_NAMES}, flags=[],
                              timings_s={"total": 0.0}, debug={"alternative_poses": []})

    monkeypatch.setattr(lm_pkg, "predict_landmarks", fake_predict)
    opts = CorrespondOptions(refit_poses_per_tip=0, refit_pose_scales=())
    res = correspond(mesh, template=template, options=opts if mirror else dc_replace(opts, mirror=None))
    err = np.linalg.norm(res.vertices - gt, axis=1).mean()
    if mirror:
        assert len(starts) == 1 and any(f.startswith("mirror_turned") for f in res.flags), res.flags
        assert err < 2.5, err
        assert not any(f.startswith("asymmetric_fit") for f in res.flags)
    else:
        assert not starts and err > 5.0, err
