"""The SIMPOP consistency bench (issue 14, item 2): its data, the rescan, the carrying of points
through the shared topology and the spread measure; and the per-artefact breakdown's grouping."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benches" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def sc():
    return _load("simpop_consistency")


def test_data_is_45_faces_on_one_topology_with_its_licence(sc):
    V, F, names = sc.load_faces()
    assert V.shape == (45, 7160, 3) and F.shape == (14050, 3) and len(names) == 45
    assert F.min() == 0 and F.max() == 7159
    d = sc.DATA.parent
    assert (d / "LICENSE").read_text().count("Apache License") >= 1 and "MeshMonk" in (d / "NOTICE").read_text()
    # the faces differ (45 identities), in mm, in one common pose
    assert np.linalg.norm(V[0] - V[1], axis=1).mean() > 1.0
    assert 100.0 < np.ptp(V[:, :, 1], axis=1).min() and np.ptp(V[:, :, 1], axis=1).max() < 300.0
    # the landmark ids: eye corners at one height, the nose tip (nearly) the most protruding, on the midline, right at -x
    M = V.mean(0)
    L = M[list(sc.SIMPOP_LANDMARKS)]
    assert np.ptp(L[:4, 1]) < 5.0
    assert M[:, 2].max() - L[6, 2] < 1.5 and abs(L[6, 0] - 0.5 * (L[1, 0] + L[2, 0])) < 3.0
    assert L[0, 0] < L[1, 0] < 0 < L[2, 0] < L[3, 0] and L[4, 0] < 0 < L[5, 0]
    assert L[7, 1] < L[6, 1] < L[1, 1]


def test_rescan_is_a_new_noisy_topology_with_holes(sc):
    V, F, _ = sc.load_faces()
    X = V[3] + sc.model_frame_shift(V)
    sv, sf, scan = sc.rescan(X, F, np.random.default_rng(0))
    assert len(sv) > 15000 and len(sv) != 7160 and sf.max() == len(sv) - 1
    R, t = scan.pose[:, :3], scan.pose[:, 3]
    assert not np.allclose(R, np.eye(3))
    # every scan point is near the face's surface once the pose is undone (noise, spikes)
    back = (sv - t) @ R
    from facecorr.geometry.closest import closest_points

    _, _, d = closest_points(X, F, back)
    assert np.median(d) < 0.4 and np.percentile(d, 99) < 1.5
    assert len(sv) < len(scan.vertices)  # the holes removed vertices
    lm = (scan.landmarks - t) @ R
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(back).query(lm)
    assert dist.max() < 2.0  # no hole at a landmark


def test_carry_and_spread(sc):
    V, F, _ = sc.load_faces()
    mean = V.mean(0)
    rng = np.random.default_rng(1)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    Xs = V[7] @ R.T + [5.0, -3.0, 2.0]
    ids = np.array([100, 2000, 3590, 7000])
    carried, dist = sc._carry(Xs[ids], Xs, F, mean)
    assert dist.max() < 1e-9 and np.abs(carried - mean[ids]).max() < 1e-9
    # a point 1 mm off the surface along the normal carries to the same place
    from facecorr.geometry.mesh import vertex_normals

    n = vertex_normals(Xs, F)[ids]
    c2, d2 = sc._carry(Xs[ids] + n, Xs, F, mean)
    assert np.allclose(d2, 1.0, atol=0.05) and np.abs(c2 - mean[ids]).max() < 0.3
    # spread: 4 faces at +-1 mm in x around a point -> 1 mm; one face not counted -> ignored
    P = np.zeros((5, 2, 3))
    P[:4, 0, 0] = [1, -1, 1, -1]
    P[4, 0, 0] = 50.0
    counted = np.ones((5, 2), bool)
    counted[4] = False
    s = sc.spread(P, counted)
    assert s[0] == pytest.approx(1.0) and s[1] == 0.0
    counted[:, 1] = [True, False, False, True, True]  # 3 of 5 < 80 %: not reported
    assert np.isnan(sc.spread(P, counted)[1])


def test_regions_cover_their_points(sc):
    from facecorr.template import load_template

    t = load_template()
    reg = sc.region_vertices(t)
    for name, pts in sc.REGIONS.items():
        ids = t.ibug68[list(pts)]
        assert set(ids[ids >= 0]) <= set(reg[name].tolist()) and 20 < len(reg[name]) < t.n_vertices // 3
    assert not set(reg["brows"]) & set(reg["mouth"])


def test_breakdown_groups_scans_by_artefact(tmp_path):
    ob = _load("ood_breakdown")
    rows = []
    for i, arts in enumerate([[], ["hair"], ["hair", "glasses"]]):
        gt = tmp_path / f"s{i}.json"
        gt.write_text(json.dumps({"artefacts": arts, "split": "ood_test"}))
        rows.append({"scan": str(tmp_path / f"s{i}.ply"), "ok": True, "dense_mean": float(i + 1),
                     "landmark_errors": {f"l{k}": float(i * 5) for k in range(8)},
                     "regions": {"right_eyebrow": [1.0 + i], "left_eyebrow": [1.0 + i], "right_eye": [2.0],
                                 "left_eye": [2.0], "nose": [3.0], "mouth": [12.0 * (i == 2)]}})
    (tmp_path / "reg").mkdir()
    (tmp_path / "reg" / "registration_per_scan.json").write_text(json.dumps(rows))
    table = dict(ob.breakdown(ob.load_rows([tmp_path / "reg"], "registration")))
    assert table["no artefact"]["n"] == 1 and table["no artefact"]["dense"] == 1.0
    assert table["hair"]["n"] == 2 and table["hair"]["dense"] == 2.5 and table["hair"]["brows"] == 2.5
    assert table["glasses"]["n"] == 1 and table["glasses"]["region_over_10"] == 100.0
    assert table["hair"]["lm_all_within_10"] == 50.0 and table["beard"] == {"n": 0, "failed": 0}
    assert table["all"]["n"] == 3
