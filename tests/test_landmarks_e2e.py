"""End to end on a small synthetic database: train, predict, CLI JSON contract, hopeless input."""

import json

import numpy as np
import pytest

from facecorr.errors import LandmarkError
from facecorr.names import LANDMARK_NAMES

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    from facecorr.landmarks.train import train
    from facecorr.synth import generate, load_index

    db = tmp_path_factory.mktemp("lmdb")
    generate(db, preset="tiny", seed=3, workers=2, expressions=["NE", "HA", "SU", "AN"], levels=[4], progress=False)
    model_path = db / "model.npz"
    model = train(db, model_path, workers=1, progress=False)
    return db, model_path, model, load_index(db)


def test_train_writes_small_valid_model(trained):
    from facecorr.landmarks.model import load_model

    db, path, model, _ = trained
    assert path.stat().st_size < 5_000_000
    m = load_model(path)
    assert m.params["n_scans"] >= 3 and m.params["n_failed"] == 0
    assert (m.search_radius > 0).all()


def _test_errors(trained, **options):
    from facecorr.io import load_mesh
    from facecorr.landmarks import predict_landmarks

    db, path, model, recs = trained
    errs, stages = [], set()
    for r in [r for r in recs if r["split"] == "test"]:
        mesh = load_mesh(r["scan"], units="mm")
        gt = json.loads(open(r["gt"]).read())["landmarks"]
        res = predict_landmarks(mesh, model=model, **options)
        assert set(res.positions) == set(LANDMARK_NAMES)
        assert all(0.0 <= c <= 1.0 for c in res.confidence.values())
        stages |= set(res.timings_s)
        errs.append([np.linalg.norm(res.positions[n] - np.asarray(gt[n])) for n in LANDMARK_NAMES])
    return np.array(errs), stages


@pytest.mark.parametrize("localise", ["patch", "bp"])
def test_predict_on_test_subject(trained, localise):
    # Protrusion start. One training subject only (the tiny preset), yet measured with the
    # default patch localisation every landmark of the 4 test scans within 8 mm (mean 3.8 mm);
    # with BP within 11 mm (mean 4.0 mm).
    errs, stages = _test_errors(trained, localise=localise)
    assert {"starts", "pose", "total", "patches" if localise == "patch" else "bp"} <= stages
    assert (errs.max(axis=1) < 15.0).all(), errs.round(1)
    assert errs.mean() < 6.0, errs.round(1)


def test_alternative_poses_are_other_readings_and_the_winner_replays(trained):
    """The start search keeps its next best poses that place the landmark graph ≥ 10 mm (mean)
    from the winner's and from each other; localising from the winner's pose, given as
    ``start_pose``, gives the prediction's landmarks again (in any frame: the scan is moved)."""
    from facecorr.io import load_mesh
    from facecorr.landmarks import predict_landmarks

    db, path, model, recs = trained
    rec = [r for r in recs if r["split"] == "test"][0]
    mesh = load_mesh(rec["scan"], units="mm")
    res = predict_landmarks(mesh, model=model, retry=False)
    alts = res.debug["alternative_poses"]
    assert 1 <= len(alts) <= 2
    r0, t0 = res.debug["pose"]
    graphs = [s * model.graph_points @ r.T + t for r, t, _, s in [(r0, t0, 0, res.debug["pose_scale"])] + alts]
    for i in range(len(graphs)):
        for j in range(i):
            assert np.linalg.norm(graphs[i] - graphs[j], axis=1).mean() >= 10.0
    from facecorr.geometry.mesh import Mesh

    moved = Mesh(mesh.vertices + [40.0, -25.0, 300.0], mesh.faces)
    winner = (r0, np.asarray(t0) + [40.0, -25.0, 300.0], res.debug["icp_rms"], res.debug["pose_scale"])
    again = predict_landmarks(moved, model=model, start_pose=winner)
    for n in LANDMARK_NAMES:
        assert np.linalg.norm(again.positions[n] - [40.0, -25.0, 300.0] - res.positions[n]) < 1e-6, n


def test_predict_paper_start(trained):
    # The paper's umbilic + FPPCA start. Before 2026-12-06 2 of these 4 test scans had all 8
    # landmarks within 10 mm and the other 2 were placed wholesale 30-110 mm off (starts on the crop
    # border, upside-down poses); with whole FP disks, per-tip poses and the whole-template choice
    # every landmark of the 4 is within 8.6 mm (mean 3.9 mm).
    errs, stages = _test_errors(trained, start_search="paper", localise="bp", retry=False)
    assert {"umbilics", "fppca", "nose", "pose", "bp", "total"} <= stages
    assert (errs.max(axis=1) < 15.0).all(), errs.round(1)
    assert errs.mean() < 6.0, errs.round(1)


def test_paper_starts_have_whole_fp_disks(trained):
    # Umbilics nearer the scan's outer border than the largest FP radius have cut-off descriptors
    # (which mimic a nose tip's): they are never nose-search starts; without the check they can be.
    from facecorr.geometry.spatial import KDTree
    from facecorr.io import load_mesh
    from facecorr.landmarks import predict_landmarks

    _, _, model, recs = trained
    rec = [r for r in recs if r["split"] == "test"][0]
    mesh = load_mesh(rec["scan"], units="mm")
    border = KDTree(mesh.vertices[mesh.outer_boundary])
    for check in (True, False):
        res = predict_landmarks(mesh, model=model, start_search="paper", localise="bp", retry=False,
                                fp_border_check=check)
        d = np.asarray(border.query(mesh.vertices[np.asarray(res.debug["starts"])])[0])
        if check:
            assert (d >= model.radii.max()).all(), d.round(1)
            assert 0 < res.debug["n_start_umbilics"] < res.debug["n_umbilics"]
        else:
            assert res.debug["n_start_umbilics"] == res.debug["n_umbilics"]


def test_cli_json_contract(trained, tmp_path):
    from facecorr.cli import main

    db, path, _, recs = trained
    scan = [r for r in recs if r["split"] == "test"][0]["scan"]
    out = tmp_path / "lm.json"
    assert main(["landmarks", scan, "--json", str(out), "--model", str(path)]) == 0
    data = json.loads(out.read_text())
    assert data["units"] == "mm"
    assert set(data["landmarks"]) == set(LANDMARK_NAMES)
    assert all(len(v) == 3 for v in data["landmarks"].values())
    assert set(data["confidence"]) == set(LANDMARK_NAMES)
    # a bad model is a one-line user error (exit 2), and no output file is written
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"junk")
    out2 = tmp_path / "lm2.json"
    assert main(["landmarks", scan, "--json", str(out2), "--model", str(bad)]) == 2
    assert not out2.exists()


def test_hopeless_input_is_flagged_or_refused(trained):
    from facecorr.landmarks import predict_landmarks
    from facecorr.geometry.mesh import Mesh

    _, _, model, _ = trained
    # a flat sheet: no face at all
    n = 60
    x, y = np.meshgrid(np.linspace(0, 150, n), np.linspace(0, 150, n))
    v = np.column_stack([x.ravel(), y.ravel(), 0.01 * np.sin(x.ravel())])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    f = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    try:
        res = predict_landmarks(Mesh(v, f), model=model)
    except LandmarkError:
        return
    assert res.flags, "a flat sheet must not give silent landmarks"
    assert min(res.confidence.values()) < 0.3


@pytest.mark.parametrize("method", ["default", "paper"])
def test_eval_landmarks_cli_writes_tables(trained, tmp_path, method):
    from facecorr.cli import main

    db, path, _, _ = trained
    out = tmp_path / "eval"
    rc = main(["eval", "landmarks", str(db), "--model", str(path), "--out", str(out), "--limit", "2",
               "--workers", "1", "--method", method])
    assert rc == 0
    rows = json.loads((out / "landmarks_per_scan.json").read_text())
    assert len(rows) == 2 and all(r["ok"] for r in rows)
    stages = set().union(*(r["timings_s"] for r in rows))
    assert ("umbilics" in stages) == (method == "paper")
    csv = (out / "landmarks_table.csv").read_text().splitlines()
    assert csv[0].startswith("landmark,mean_mm") and len(csv) == 1 + len(LANDMARK_NAMES)
    assert (out / "landmarks.png").stat().st_size > 10_000
    assert all(np.asarray(r["predicted"]).shape == (len(LANDMARK_NAMES), 3) for r in rows)


def _cut(mesh, keep):
    """The sub-mesh of the faces whose 3 vertices are kept (unused vertices dropped)."""
    from facecorr.geometry.mesh import Mesh

    f = mesh.faces[keep[mesh.faces].all(axis=1)]
    used = np.unique(f)
    remap = np.full(mesh.n_vertices, -1)
    remap[used] = np.arange(len(used))
    return Mesh(mesh.vertices[used], remap[f])


@pytest.mark.parametrize("damage", ["half_face", "hole_over_nose"])
def test_damaged_face_is_flagged_or_refused(trained, damage):
    from facecorr.io import load_mesh
    from facecorr.landmarks import predict_landmarks

    _, _, model, recs = trained
    rec = [r for r in recs if r["split"] == "test"][0]
    mesh = load_mesh(rec["scan"], units="mm")
    gt = json.loads(open(rec["gt"]).read())["landmarks"]
    tip = np.asarray(gt["nose_tip"])
    if damage == "half_face":
        # everything on the left eye's side of the plane through the nose tip and subnasal
        axis = np.asarray(gt["left_outer_eye_corner"]) - np.asarray(gt["right_outer_eye_corner"])
        keep = (mesh.vertices - tip) @ axis < 0
    else:
        keep = np.linalg.norm(mesh.vertices - tip, axis=1) > 18.0
    try:
        res = predict_landmarks(_cut(mesh, keep), model=model)
    except LandmarkError as e:
        assert str(e)
        return
    # measured: both raise graph_off_surface:nose_tip (the half face also implausible_face_scale
    # and patch_slid on 7 landmarks); a whole-graph failure flag, not only low confidence
    assert any(f.startswith(("graph_off_surface", "poor_face_fit", "implausible")) for f in res.flags), res.flags


def test_locate_landmarks_refined_by_the_registration(trained, tmp_path):
    """``facecorr landmarks`` writes the landmarks read off the registered template (the same as
    correspond's ``landmarks_registered``), ``--fast`` the prediction alone (the same as
    predict_landmarks); on the tiny preset's test scans the refined ones are no worse."""
    from facecorr.cli import main
    from facecorr.io import load_mesh
    from facecorr.landmarks import predict_landmarks
    from facecorr.pipeline import CorrespondOptions, correspond, locate_landmarks

    db, path, model, recs = trained
    errs = {"fast": [], "refined": []}
    for k, r in enumerate([r for r in recs if r["split"] == "test"][:2]):
        mesh = load_mesh(r["scan"], units="mm")
        gt = json.loads(open(r["gt"]).read())["landmarks"]
        fast = locate_landmarks(mesh, model=model, refine=False)
        ref = locate_landmarks(mesh, model=model)
        pred = predict_landmarks(mesh, model=model)
        reg = correspond(mesh, model=model, options=CorrespondOptions(neutral=None))
        for n in LANDMARK_NAMES:
            np.testing.assert_array_equal(fast.positions[n], pred.positions[n])
            np.testing.assert_allclose(ref.positions[n], reg.landmarks_registered[n], atol=1e-6)
            np.testing.assert_allclose(ref.debug["predicted"][n], pred.positions[n], atol=1e-9)
            errs["fast"].append(np.linalg.norm(fast.positions[n] - np.asarray(gt[n])))
            errs["refined"].append(np.linalg.norm(ref.positions[n] - np.asarray(gt[n])))
        if k == 0:  # the CLI: refined by default, --fast the prediction
            paper = predict_landmarks(mesh, model=model, start_search="paper", localise="bp")
            for k_flag, (flag, want) in enumerate((([], ref), (["--fast"], fast), (["--method", "fast"], fast),
                                                   (["--method", "paper"], paper))):
                out = tmp_path / f"lm{k_flag}.json"
                assert main(["landmarks", r["scan"], "--json", str(out), "--model", str(path), *flag]) == 0
                data = json.loads(out.read_text())["landmarks"]
                for n in LANDMARK_NAMES:
                    np.testing.assert_allclose(data[n], want.positions[n], atol=1e-9)
    assert np.mean(errs["refined"]) <= np.mean(errs["fast"]) + 0.5, {k: np.mean(v) for k, v in errs.items()}
