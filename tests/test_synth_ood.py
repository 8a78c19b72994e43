"""The out-of-model preset (issue 14): identities, warps, feature changes, artefacts, splits,
ground truth and determinism, on a tiny run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facecorr.cli import main as cli_main
from facecorr.evaluation.metrics import dense_error
from facecorr.io import load_mesh
from facecorr.names import LANDMARK_NAMES
from facecorr.synth import generate, load_ict, load_index
from facecorr.synth.artefacts import LABELS, SHARES, draw_plan, scanner_overrides
from facecorr.synth.model import deform
from facecorr.synth.ood import FEATURES, OODConfig, feature_displacement, ood_identity, ood_split, smooth_warp
from facecorr.synth.ood_preset import make_ood_scan, ood_model_vertices, subject_of
from facecorr.synth.scanner import closest_point_on_mesh

SEED = 5


def _unpose(x, pose):
    return (np.asarray(x, float) - pose[:, 3]) @ pose[:, :3]


def _true_surface_distance(points_model, V):
    """Distance (mm) of model-frame points to the true head surface (the ICT triangles of V)."""
    d, _ = closest_point_on_mesh(points_model, V, load_ict().triangles, 8.0)
    return d


@pytest.fixture(scope="module")
def neutral():
    m = load_ict()
    X = deform(m, ood_identity(np.random.default_rng(11), 100), np.zeros(len(m.expression)))
    return m, X, X[m.landmarks68]


def test_identity_leading_modes_at_2_to_3_sd():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w = ood_identity(rng, 100)
        assert np.all((np.abs(w[:10]) >= 2.0) & (np.abs(w[:10]) <= 3.0))
        assert np.all(np.abs(w[10:]) <= 2.5)
    sub = subject_of(SEED, "M0002")
    assert np.all(np.abs(sub.identity[:10]) >= 2.0)


def test_warp_smooth_and_in_range(neutral):
    m, X, _ = neutral
    face = X[m.part_id == 0]
    for k in range(8):
        w = smooth_warp(np.random.default_rng(k), face, OODConfig())
        d = w(face)
        peak = np.linalg.norm(d, axis=1).max()
        assert 3.0 - 1e-9 <= peak <= 8.0 + 1e-9
        assert np.all((w.scales >= 30.0) & (w.scales <= 60.0))
        # smooth: no displacement difference steeper than the analytic bound, which is small
        L = w.lipschitz_bound()
        assert L < 0.5
        rng = np.random.default_rng(k)
        a = face[rng.integers(0, len(face), 3000)]
        b = a + rng.normal(0.0, 2.0, a.shape)
        ratio = np.linalg.norm(w(a) - w(b), axis=1) / np.linalg.norm(a - b, axis=1)
        assert ratio.max() <= L + 1e-9
        # non-linear: an affine map cannot explain it
        A = np.hstack([face, np.ones((len(face), 1))])
        coef, *_ = np.linalg.lstsq(A, d, rcond=None)
        assert np.sqrt(np.mean(np.sum((A @ coef - d) ** 2, axis=1))) > 0.3


@pytest.mark.parametrize("s", [0.8, 1.2])
def test_feature_changes_move_the_right_points(neutral, s):
    m, X, p = neutral

    def moved(feature):
        D = feature_displacement(X, p, {feature: s})
        return p + D[m.landmarks68], np.linalg.norm(D[m.landmarks68], axis=1)

    q, d = moved("eye_width")
    for o, i in ((36, 39), (42, 45)):
        assert abs((q[i, 0] - q[o, 0]) / (p[i, 0] - p[o, 0]) - s) < 1e-9
    assert d[list(range(0, 36)) + list(range(48, 68))].max() < 0.05
    q, d = moved("eye_spacing")
    cr, cl = q[36:42].mean(0), q[42:48].mean(0)
    assert abs((cl[0] - cr[0]) / (p[42:48, 0].mean() - p[36:42, 0].mean()) - s) < 1e-9
    assert d[27:36].max() < 0.5 and d[48:68].max() < 0.05
    q, d = moved("nose_length")
    assert abs((q[27, 1] - q[33, 1]) / (p[27, 1] - p[33, 1]) - s) < 1e-9
    assert d[list(range(17, 27)) + [36, 45, 8]].max() < 0.05
    q, d = moved("nose_width")
    assert abs((q[35, 0] - q[31, 0]) / (p[35, 0] - p[31, 0]) - s) < 1e-9
    assert d[list(range(17, 27)) + list(range(36, 48)) + [8, 48, 54, 57]].max() < 0.05
    for feat, axis in (("brow_height", 1), ("brow_projection", 2)):
        q, d = moved(feat)
        for brow, eye in ((range(17, 22), range(36, 42)), (range(22, 27), range(42, 48))):
            brow, eye = list(brow), list(eye)
            before = p[brow, axis].mean() - p[eye, axis].mean()
            after = q[brow, axis].mean() - p[eye, axis].mean()
            assert abs(after / before - s) < 1e-9
        assert d[[36, 39, 42, 45] + list(range(27, 36)) + list(range(48, 68))].max() < 0.05
    q, d = moved("lip_thickness")
    y_st = p[60:68, 1].mean()
    assert abs((q[51, 1] - y_st) / (p[51, 1] - y_st) - s) < 1e-9
    assert abs((q[57, 1] - y_st) / (p[57, 1] - y_st) - s) < 1e-9
    assert d[list(range(17, 48))].max() < 0.05
    q, d = moved("chin_slope")
    slope0 = (p[8, 2] - p[57, 2]) / (p[8, 1] - p[57, 1])
    slope1 = (q[8, 2] - q[57, 2]) / (q[8, 1] - q[57, 1])
    assert abs(slope1 / slope0 - s) < 0.06 and abs(q[8, 2] - p[8, 2]) > 0.01
    assert d[17:68].max() < 0.05
    D = feature_displacement(X, p, {"forehead_slope": s})
    assert np.linalg.norm(D[m.landmarks68], axis=1).max() < 0.05  # no iBUG point is on the forehead
    top = (np.abs(X[:, 0]) < 4.0) & (X[:, 1] > p[17:27, 1].max() + 30.0) & (X[:, 1] < p[17:27, 1].max() + 60.0) \
        & (X[:, 2] > p[27, 2] - 30.0)
    assert np.abs(D[top, 2]).min() > 0.05 and np.abs(D[top][:, :2]).max() == 0.0
    with pytest.raises(ValueError):
        feature_displacement(X, p, {"ear_size": 1.1})
    assert set(subject_of(SEED, "F0001").factors) == set(FEATURES)
    assert all(0.8 <= f <= 1.2 for f in subject_of(SEED, "F0001").factors.values())


def test_plans_draw_every_kind_at_its_share():
    rng = np.random.default_rng(0)
    plans = [draw_plan(rng) for _ in range(2000)]
    for kind, share in SHARES.items():
        got = np.mean([kind in p for p in plans])
        assert abs(got - share) < 0.04, kind
    targets = [p["resolution"]["target_vertices"] for p in plans if "resolution" in p]
    assert 5000 <= min(targets) < 8000 and 200000 < max(targets) <= 300000
    assert {p["colour"]["source"] for p in plans if "colour" in p} == {"vertex", "texture"}
    assert scanner_overrides({"shoulders": {}})["crop"] == "none"


def _scan(plan, subject="F0001", expr="HA"):
    scan, _, labels, got_plan, details = make_ood_scan(SEED, subject, expr, 4, plan=plan)
    assert got_plan == plan
    V, _ = ood_model_vertices(SEED, subject, expr, 4)
    return scan, labels, details, V


def _check_ground_truth(scan, labels, V):
    """Dense truth exact on the true face; landmarks on the true surface, off the artefacts."""
    m = load_ict()
    ok = scan.tri >= 0
    assert (labels[~ok] >= LABELS["glasses"]).all()
    corners = V[m.triangles[scan.tri[ok]]]
    truth = np.einsum("sk,skd->sd", scan.bary[ok], corners)
    assert np.abs(_unpose(scan.clean[ok], scan.pose) - truth).max() < 1e-6
    lm = _unpose(scan.landmarks, scan.pose)
    assert _true_surface_distance(lm, V).max() < 1e-6
    ib = _unpose(scan.ibug68[np.isfinite(scan.ibug68).all(1)], scan.pose)
    assert _true_surface_distance(ib, V).max() < 1e-6
    added = ~ok
    if added.any():
        from scipy.spatial import cKDTree

        d, _ = cKDTree(_unpose(scan.clean[added], scan.pose)).query(lm)
        assert d.min() > 2.0


def test_each_artefact_appears_and_the_truth_stays_exact():
    base, lab0, _, V = _scan({})
    assert (lab0 == 0).all() and (base.tri >= 0).all()
    _check_ground_truth(base, lab0, V)
    X0 = _unpose(base.clean, base.pose)
    ib = V[load_ict().landmarks68]

    hair, lab, det, _ = _scan({"hair": {}})
    _check_ground_truth(hair, lab, V)
    h = lab == LABELS["hair"]
    assert h.sum() > 500 and det["hair"]["removed"] > 100 and len(hair.vertices) < len(base.vertices)
    lift = np.linalg.norm(hair.vertices[h] - hair.clean[h], axis=1)
    assert lift.max() > 2.0 and np.percentile(lift, 50) > 0.2
    assert _unpose(hair.clean[h], hair.pose)[:, 1].min() > ib[36:48, 1].max()  # above the eyes

    beard, lab, det, _ = _scan({"beard": {}}, subject="M0001")
    _check_ground_truth(beard, lab, V := ood_model_vertices(SEED, "M0001", "HA", 4)[0])
    b = lab == LABELS["beard"]
    assert b.sum() > 500
    Xb = _unpose(beard.clean[b], beard.pose)
    ibm = V[load_ict().landmarks68]
    assert Xb[:, 1].max() < ibm[29, 1] + 1.0  # below the middle of the nose
    lips = ibm[48:60]
    inside = (np.abs(Xb[:, 0] - lips[:, 0].mean()) < 0.3 * np.ptp(lips[:, 0])) & \
             (np.abs(Xb[:, 1] - lips[:, 1].mean()) < 0.3 * np.ptp(lips[:, 1]))
    assert not inside.any()  # the lips are free
    assert np.linalg.norm(beard.vertices[b] - beard.clean[b], axis=1).max() > 0.1

    V = ood_model_vertices(SEED, "F0001", "HA", 4)[0]
    gl, lab, det, _ = _scan({"glasses": {}})
    _check_ground_truth(gl, lab, V)
    g = lab == LABELS["glasses"]
    assert g.sum() > 300 and (gl.tri[g] == -1).all() and det["glasses"]["removed"] > 0
    Xg = _unpose(gl.clean[g], gl.pose)
    front = Xg[:, 2] > ib[36:48, 2].max() + 5.0
    assert front.mean() > 0.5  # most of the frame floats in front of the eyes
    assert np.abs(Xg[front, 1] - ib[36:48, 1].mean()).max() < 30.0

    chin, lab, det, _ = _scan({"missing_chin": {}})
    _check_ground_truth(chin, lab, V)
    cut = det["missing_chin"]["cut_y_mm"]
    Xc = _unpose(chin.clean, chin.pose)
    assert Xc[:, 1].min() > cut - 12.0 and X0[:, 1].min() < cut - 20.0
    assert np.isnan(chin.ibug68[8]).all() and np.isfinite(base.ibug68[8]).all()
    assert np.isfinite(chin.landmarks).all()

    sh, lab, det, _ = _scan({"shoulders": {}})
    _check_ground_truth(sh, lab, V)
    c = lab == LABELS["clothing"]
    assert c.sum() > 5000 and (sh.tri[c] == -1).all()
    Xs = _unpose(sh.clean[c], sh.pose)
    assert Xs[:, 1].max() < ib[8, 1] and np.ptp(Xs[:, 0]) > 300.0

    lo, lab, det, _ = _scan({"resolution": {"target_vertices": 8000}})
    _check_ground_truth(lo, lab, V)
    assert 4000 < len(lo.vertices) < 16000 and det["resolution"]["vertices"] == len(lo.vertices)


def test_database_contract_splits_colour_and_determinism(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    kw = dict(preset="bu3dfe-ood", seed=SEED, subjects=3, expressions=("NE", "HA", "SU"), levels=[4], progress=False)
    generate(a, workers=2, **kw)
    generate(b, workers=1, **kw)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    recs = load_index(a)
    assert len(recs) == 9
    assert [r["split"] for r in recs if r["expression"] == "NE"] == ["ood_test", "ood_test", "ood_holdout"]
    assert [ood_split(i) for i in range(6)] == ["ood_test", "ood_test", "ood_holdout"] * 2
    kinds = set()
    for r in recs:
        gt = json.loads(open(r["gt"]).read())
        assert gt["split"] == r["split"] and isinstance(gt["artefacts"], list)
        assert set(gt["artefact_details"]) == set(gt["artefacts"])
        assert list(gt["landmarks"]) == list(LANDMARK_NAMES) and len(gt["ibug68"]) == 68
        assert set(gt["ood"]["features"]) == set(FEATURES)
        kinds |= set(gt["artefacts"])
        mesh = load_mesh(r["scan"], units="mm", merge_duplicates=False)
        d = np.load(r["dense"])
        assert len(d["tri"]) == mesh.n_vertices == len(d["artefact_label"])
        if "colour" in gt["artefacts"]:
            assert gt["colour"]["source"] == gt["artefact_details"]["colour"]["source"]
            assert mesh.color_source is not None
            assert r["scan"].endswith(".obj" if gt["colour"]["source"] == "texture" else ".ply")
        else:
            assert mesh.color_source is None
    assert kinds  # this seed gives artefacts


def test_dense_error_skips_geometry_without_correspondence():
    from facecorr.template import load_template

    t = load_template()
    face = int(np.flatnonzero(t.ict_face_to_template_face >= 0)[0])
    corners = t.vertices[t.faces[t.ict_face_to_template_face[face]]]
    dense = {"tri": np.array([face, -1]), "bary": np.array([[1.0, 0, 0], [0, 0, 0]]),
             "clean": np.vstack([corners[0], [1e3, 1e3, 1e3]])}
    err, mask = dense_error(t.vertices, dense, t, return_mask=True)
    assert mask.tolist() == [True, False] and err.tolist() == [0.0]
    with pytest.raises(ValueError):
        dense_error(t.vertices, {**dense, "tri": np.array([face, -2])}, t)


def test_eval_split_option(tmp_path, capsys):
    db = tmp_path / "db"
    generate(db, preset="bu3dfe-ood", seed=SEED, subjects=3, expressions=("NE",), progress=False, workers=1)
    rc = cli_main(["eval", "landmarks", str(db), "--out", str(tmp_path / "lm"), "--quiet", "--no-png"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "ood_holdout, ood_test" in err[0] and "--split" in err[0]
    rc = cli_main(["eval", "landmarks", str(db), "--split", "ood_holdout", "--out", str(tmp_path / "lm"), "--quiet",
                   "--no-png", "--workers", "1"])
    rows = json.loads((tmp_path / "lm" / "landmarks_per_scan.json").read_text())
    assert [r["scan"].split("/")[-1].split(".")[0] for r in rows] == ["F0002_NE00_F3D"]
    assert all(r["ok"] for r in rows) and rc == 0


def test_ood_preset_refuses_colour_and_crop(tmp_path, capsys):
    rc = cli_main(["synth", str(tmp_path / "x"), "--preset", "bu3dfe-ood", "--colour", "vertex", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "bu3dfe-ood" in err[0]
    assert not (tmp_path / "x" / "index.json").exists()
