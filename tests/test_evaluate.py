"""facecorr.evaluate on exact cases: zero error at the truth, known errors for known shifts, MHD
against a brute-force numpy reference, Table 3 summaries computed by hand, ground-truth files."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from facecorr.evaluation import metrics as evaluate
from facecorr import names
from facecorr.errors import FacecorrError
from facecorr.template import ICT_MODEL_PATH


@pytest.fixture(scope="module")
def ict():
    with np.load(ICT_MODEL_PATH) as d:
        return {k: d[k] for k in ("neutral", "triangles", "expression", "expression_names")}


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _posed(t, seed=0):
    """A template expression in a random rigid pose, and the pose."""
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(0, 1, t.n_blendshapes)
    r, s = _rotation(seed), rng.normal(0, 50, 3)
    return t.expression(alpha) @ r.T + s, alpha, r, s


def test_region_errors_zero_at_truth_and_known_shift(t):
    reg, *_ = _posed(t)
    gt = reg[t.ibug68]
    errs = evaluate.region_errors(reg, gt, t)
    assert list(errs) == list(names.IBUG68_REGIONS)
    for region, e in errs.items():
        assert e.shape == (len(names.IBUG68_REGIONS[region]),)
        np.testing.assert_allclose(e, 0.0, atol=1e-12)
    shifted = evaluate.region_errors(reg + np.array([3.0, 4.0, 0.0]), gt, t)
    for e in shifted.values():
        np.testing.assert_allclose(e, 5.0, rtol=1e-12)


def test_region_errors_missing_points(t):
    reg, *_ = _posed(t, 1)
    gt = reg[t.ibug68] + np.array([0.0, 0.0, 1.0])
    gt[[17, 50, 51]] = np.nan
    e = evaluate.region_errors(reg, gt, t)
    assert len(e["right_eyebrow"]) == 4 and len(e["mouth"]) == 10
    full = evaluate.region_errors(reg, gt, t, keep_missing=True)
    assert np.isnan(full["right_eyebrow"][0]) and np.isnan(full["mouth"][2:4]).all()
    np.testing.assert_allclose(full["nose"], 1.0)


def test_region_errors_bad_input(t):
    with pytest.raises(ValueError):
        evaluate.region_errors(np.zeros((10, 3)), np.zeros((68, 3)), t)
    with pytest.raises(ValueError):
        evaluate.region_errors(t.vertices, np.zeros((67, 3)), t)


def _dense_scan(t, ict, alpha, r, s, n=4000, seed=0):
    """Sample scan points on the posed full ICT model (inside and outside the template)."""
    rng = np.random.default_rng(seed)
    names_ = [str(x) for x in ict["expression_names"]]
    from facecorr.template import BLENDSHAPE_RECIPES

    full = ict["neutral"].astype(np.float64)
    for a, (_, recipe) in zip(alpha, BLENDSHAPE_RECIPES):
        for src, w in recipe.items():
            full = full + a * w * ict["expression"][names_.index(src)].astype(np.float64)
    full = full @ r.T + s
    tri = rng.integers(0, len(ict["triangles"]), n)
    bary = rng.dirichlet(np.ones(3), n)
    clean = np.einsum("sk,skd->sd", bary, full[ict["triangles"][tri]])
    return {"tri": tri.astype(np.int32), "bary": bary.astype(np.float32), "clean": clean.astype(np.float32)}


def test_dense_error_exact_cases(t, ict):
    reg, alpha, r, s = _posed(t, 2)
    dense = _dense_scan(t, ict, alpha, r, s)
    err, mask = evaluate.dense_error(reg, dense, t, return_mask=True)
    inside = t.ict_face_to_template_face[dense["tri"]] >= 0
    assert np.array_equal(mask, inside) and 0 < mask.sum() < len(mask)
    assert err.shape == (mask.sum(),)
    assert err.max() < 1e-3  # float32 storage of bary/clean only
    shift = np.array([0.0, 2.0, 0.0])
    np.testing.assert_allclose(evaluate.dense_error(reg + shift, dense, t), 2.0, atol=1e-3)
    # a wrong expression gives a real error
    assert evaluate.dense_error(t.vertices @ r.T + s, dense, t).mean() > 0.5


def test_dense_error_bad_input(t):
    reg = t.vertices
    with pytest.raises(ValueError):
        evaluate.dense_error(reg, {"tri": np.array([0]), "bary": np.ones((1, 3))}, t)
    with pytest.raises(ValueError):
        evaluate.dense_error(reg, {"tri": np.array([10**7]), "bary": np.ones((1, 3)) / 3,
                                   "clean": np.zeros((1, 3))}, t)


def _mhd_brute(p, f):
    d = np.linalg.norm(p[:, None, :] - f[None, :, :], axis=2)
    return d.min(axis=1).mean()


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 40), st.just(3)), elements=st.floats(-100, 100)),
       arrays(np.float64, st.tuples(st.integers(1, 60), st.just(3)), elements=st.floats(-100, 100)))
def test_mhd_matches_brute_force(p, f):
    assert evaluate.mhd(p, f) == pytest.approx(_mhd_brute(p, f), rel=1e-9, abs=1e-9)


def test_mhd_exact_values(t):
    v = t.vertices
    assert evaluate.mhd(v, v) == 0.0
    rng = np.random.default_rng(3)
    f = rng.normal(size=(500, 3)) * 30
    p = rng.normal(size=(300, 3)) * 30
    assert evaluate.mhd(p, f) == pytest.approx(_mhd_brute(p, f), rel=1e-12)
    # one-directional: P a subset of F has zero MHD, not the other way round
    assert evaluate.mhd(f[:100], f) == 0.0 and evaluate.mhd(f, f[:100]) > 0
    with pytest.raises(ValueError):
        evaluate.mhd(np.zeros((0, 3)), f)
    with pytest.raises(ValueError):
        evaluate.mhd(p, np.full((3, 3), np.nan))


def test_summarize_regions_by_hand():
    scans = [
        {"nose": np.array([1.0, 2.0, 3.0]), "mouth": np.array([5.0, 25.0])},
        {"nose": np.array([9.0, 11.0]), "mouth": np.array([np.nan, 31.0])},
        {"nose": np.array([]), "mouth": np.array([4.0])},
    ]
    rows = {r["region"]: r for r in evaluate.summarize_regions(scans)}
    assert list(rows) == ["nose", "mouth"]  # regions nobody measured are omitted
    nose = np.array([1, 2, 3, 9, 11.0])
    assert rows["nose"]["mean"] == pytest.approx(nose.mean())
    assert rows["nose"]["std"] == pytest.approx(nose.std())
    assert rows["nose"]["max"] == 11.0
    assert rows["nose"]["n_scans"] == 2 and rows["nose"]["n_points"] == 5  # empty scan left out
    assert (rows["nose"]["T10"], rows["nose"]["T20"], rows["nose"]["T30"]) == (50.0, 100.0, 100.0)
    m = rows["mouth"]
    assert m["n_points"] == 4 and m["max"] == 31.0
    # worst per scan: 25, 31, 4 -> under 10: 1/3, under 20: 1/3, under 30: 2/3
    assert m["T10"] == pytest.approx(100 / 3) and m["T20"] == pytest.approx(100 / 3)
    assert m["T30"] == pytest.approx(200 / 3)
    md = evaluate.format_region_table(list(rows.values()))
    assert "| nose | 5.20 ± " in md and md.count("\n") == 4


def _write_gt(tmp_path, t, ibug=None, **over):
    sub = tmp_path / "F0001"
    sub.mkdir(exist_ok=True)
    pts = t.vertices[t.ibug68]
    np.savez(sub / "F0001_NE00_F3D_dense.npz", tri=np.array([0, 1], np.int32),
             bary=np.full((2, 3), 1 / 3, np.float32), clean=np.zeros((2, 3), np.float32),
             pose=np.eye(3, 4))
    doc = {"scan": "F0001_NE00_F3D.ply", "subject": "F0001", "expression": "NE", "level": 0,
           "split": "train", "units": "mm",
           "landmarks": {n: t.vertices[i].tolist() for n, i in t.landmarks.items()},
           "ibug68": ibug if ibug is not None else [p.tolist() for p in pts[:67]] + [None],
           "dense": "F0001_NE00_F3D_dense.npz"}
    doc.update(over)
    path = sub / "F0001_NE00_F3D.json"
    path.write_text(json.dumps(doc))
    return path


def test_load_ground_truth(tmp_path, t):
    path = _write_gt(tmp_path, t)
    gt = evaluate.load_ground_truth(path)
    assert gt["subject"] == "F0001" and gt["level"] == 0 and gt["split"] == "train"
    assert gt["scan"] == str((path.parent / "F0001_NE00_F3D.ply").resolve())
    assert gt["ibug68"].shape == (68, 3) and np.isnan(gt["ibug68"][67]).all()
    np.testing.assert_allclose(gt["ibug68"][:67], t.vertices[t.ibug68[:67]])
    np.testing.assert_allclose(gt["landmarks"]["nose_tip"], t.vertices[t.landmarks["nose_tip"]])
    assert gt["dense"]["tri"].dtype == np.int64 and gt["dense"]["pose"].shape == (3, 4)
    errs = evaluate.region_errors(t.vertices, gt["ibug68"], t)
    assert all(np.allclose(e, 0) for e in errs.values())
    assert evaluate.load_ground_truth(path, load_dense=False)["dense"] is None


def test_load_ground_truth_errors(tmp_path, t):
    with pytest.raises(FacecorrError, match="not found"):
        evaluate.load_ground_truth(tmp_path / "nope.json")
    with pytest.raises(FacecorrError, match="68 entries"):
        evaluate.load_ground_truth(_write_gt(tmp_path, t, ibug=[[0, 0, 0]] * 5))
    with pytest.raises(FacecorrError, match="landmarks"):
        evaluate.load_ground_truth(_write_gt(tmp_path, t, landmarks={"nose_tip": [0, 0, 0]}))
    with pytest.raises(FacecorrError, match="dense"):
        evaluate.load_ground_truth(_write_gt(tmp_path, t, dense="missing.npz"))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(FacecorrError, match="unreadable"):
        evaluate.load_ground_truth(bad)


def test_landmark_errors_and_summary():
    gt = {n: np.zeros(3) for n in names.LANDMARK_NAMES}
    pred = {n: np.array([0.0, 0.0, 2.0 * i]) for i, n in enumerate(names.LANDMARK_NAMES)}
    e = evaluate.landmark_errors(pred, gt)
    assert list(e) == list(names.LANDMARK_NAMES)
    assert [e[n] for n in names.LANDMARK_NAMES] == [2.0 * i for i in range(8)]
    del pred["subnasal"]
    assert np.isnan(evaluate.landmark_errors(pred, gt)["subnasal"])
    scans = [{"nose_tip": 4.0, "subnasal": 12.0}, {"nose_tip": 8.0, "subnasal": float("nan")},
             {"nose_tip": 25.0}]
    rows = {r["landmark"]: r for r in evaluate.summarize_landmarks(scans)}
    assert list(rows) == ["nose_tip", "subnasal"]
    assert rows["nose_tip"]["mean"] == pytest.approx(37 / 3) and rows["nose_tip"]["max"] == 25.0
    assert rows["nose_tip"]["T10"] == pytest.approx(200 / 3) and rows["nose_tip"]["T30"] == 100.0
    assert rows["subnasal"]["n_scans"] == 1 and rows["subnasal"]["T10"] == 0.0
    assert evaluate.format_region_table(list(rows.values())).startswith("| Landmark |")


def test_perfect_registration_of_a_synthetic_scan(tmp_path, t):
    """Across the helpers' contracts: the model head of a synthetic scan, read at the template's
    vertices and posed by the scan's ``pose``, has zero dense, region and landmark error."""
    from facecorr.io import load_mesh
    from facecorr.synth import generate, load_index, model_vertices

    generate(tmp_path, preset="tiny", seed=3, workers=1, subjects=1, expressions=["HA"], levels=[4],
             progress=False)
    rec = load_index(tmp_path)[0]
    gt = evaluate.load_ground_truth(rec["gt"])
    head, _ = model_vertices(3, rec["subject"], rec["expression"], rec["level"])
    pose = gt["dense"]["pose"]
    perfect = head[t.ict_vertex] @ pose[:, :3].T + pose[:, 3]
    dense, mask = evaluate.dense_error(perfect, gt["dense"], t, return_mask=True)
    # the BU-3DFE-like crop reaches past the template (forehead, cheeks), so ~60-70 % of the scan is measured
    assert mask.mean() > 0.5 and dense.max() < 1e-3  # float32 storage only
    # iBUG/landmark ground truth is the model point snapped onto the scanned (resampled, ~1 mm
    # grid) surface, as an annotator clicks it: the model vertex is off by the chord error only
    # (a fold, e.g. a squinting eye contour, is deeper: the snap is capped at 3 mm for iBUG points
    # and 6 mm for the 8 landmarks, ScannerConfig.landmark_snap_mm / landmark8_snap_mm).
    regions = evaluate.region_errors(perfect, gt["ibug68"], t)
    assert all(len(e) and e.max() <= 3.0 + 1e-6 for e in regions.values())
    assert np.median(np.concatenate(list(regions.values()))) < 0.5
    lm = evaluate.landmark_errors({n: perfect[i] for n, i in t.landmarks.items()}, gt["landmarks"])
    assert max(lm.values()) <= 6.0 + 1e-6 and np.median(list(lm.values())) < 0.5
    # the rest pose, rigidly placed, is millimetres off (the subject's identity and expression)
    assert evaluate.dense_error(t.vertices @ pose[:, :3].T + pose[:, 3], gt["dense"], t).mean() > 2.0
    scan = load_mesh(rec["scan"])
    assert evaluate.mhd(perfect, scan.vertices) < 3.0
