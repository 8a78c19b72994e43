"""The synthetic scan database (facecorr.synth) on a reduced tiny run, generated once per session."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from facecorr.errors import FacecorrError
from facecorr.io import load_mesh
from facecorr.names import LANDMARK_IBUG68, LANDMARK_NAMES
from facecorr.synth import (SynthError, generate, generate_scan, load_ict, load_index, model_vertices, scan_list,
                            subject_split)
from facecorr.cli.synth import main as synth_main
from facecorr.synth.scanner import closest_point_on_triangles

SEED = 3
EXPRESSIONS = ("NE", "HA", "SU")  # closed mouth, squint, open mouth


def closest_point_ericson(p, a, b, c):
    """Reference: closest point of triangle abc to p by Voronoi regions (Ericson, Real-Time
    Collision Detection, 5.1.5), one point at a time."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return a
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return a + d1 / (d1 - d3) * ab
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return a + d2 / (d2 - d6) * ac
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
    denom = 1.0 / (va + vb + vc)
    return a + ab * (vb * denom) + ac * (vc * denom)


def distance_to_mesh_reference(points, V, F, radius=6.0):
    """(K,) distance of each point to the triangles having a vertex within ``radius`` mm."""
    tree = cKDTree(V)
    out = np.full(len(points), np.inf)
    for k, p in enumerate(points):
        near = np.zeros(len(V), bool)
        near[tree.query_ball_point(p, radius)] = True
        for f in F[near[F].any(1)]:
            out[k] = min(out[k], np.linalg.norm(p - closest_point_ericson(p, *V[f])))
    return out


def test_closest_point_on_triangles_matches_ericson():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(400, 3, 3))
    tri[:20, 2] = tri[:20, 0] + 0.5 * (tri[:20, 1] - tri[:20, 0])  # degenerate (collinear) ones
    p = 2.0 * rng.normal(size=(400, 3))
    d, q = closest_point_on_triangles(p, tri)
    ref = np.array([closest_point_ericson(p[i], *tri[i]) for i in range(20, len(p))])
    np.testing.assert_allclose(q[20:], ref, atol=1e-9)
    np.testing.assert_allclose(d[20:], np.linalg.norm(p[20:] - ref, axis=1), atol=1e-9)

    def segment_distance(x, u, v):
        t = np.clip((x - u) @ (v - u) / ((v - u) @ (v - u)), 0, 1)
        return np.linalg.norm(x - (u + t * (v - u)))

    for i in range(20):  # a degenerate triangle is its edges
        a, b, c = tri[i]
        ref_d = min(segment_distance(p[i], a, b), segment_distance(p[i], b, c), segment_distance(p[i], c, a))
        assert abs(d[i] - ref_d) < 1e-9 and abs(np.linalg.norm(p[i] - q[i]) - d[i]) < 1e-9


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "db"
    generate(out, preset="tiny", seed=SEED, workers=2, expressions=EXPRESSIONS, levels=[4], progress=False)
    return out


def _scan(rec):
    m = load_mesh(rec["scan"], units="mm", merge_duplicates=False)
    with open(rec["gt"]) as fh:
        gt = json.load(fh)
    return m, gt, dict(np.load(rec["dense"]))


def _gt_points(gt):
    """(8 + k, 3) the 8 landmarks and the iBUG-68 points present on the scan."""
    ib = [p for p in gt["ibug68"] if p is not None]
    return np.array([gt["landmarks"][n] for n in LANDMARK_NAMES] + ib, float)


def test_index_and_json_contract(db):
    with open(db / "index.json") as fh:
        index = json.load(fh)
    assert index["preset"] == "tiny" and index["seed"] == SEED
    assert len(index["scans"]) == 2 * len(EXPRESSIONS)
    subjects = sorted({r["subject"] for r in index["scans"]})
    assert subjects == ["F0001", "M0001"]
    assert {r["split"] for r in index["scans"]} == {"train", "test"}  # tiny: one subject each
    for r in index["scans"]:
        assert set(r) == {"scan", "gt", "subject", "expression", "level", "split"}
        assert r["scan"] == f"{r['subject']}/{r['subject']}_{r['expression']}{r['level']:02d}_F3D.ply"
        assert r["gt"] == r["scan"][:-4] + ".json"
        assert r["level"] == (0 if r["expression"] == "NE" else 4)
        assert r["split"] == subject_split(r["subject"])
    recs = load_index(db)
    assert len(recs) == len(index["scans"])
    for rec, raw in zip(recs, index["scans"]):
        for key in ("scan", "gt", "dense"):
            assert Path(rec[key]).is_absolute() and Path(rec[key]).is_file()
        with open(rec["gt"]) as fh:
            gt = json.load(fh)
        assert set(gt) == {"scan", "subject", "expression", "level", "split", "units", "landmarks", "ibug68", "dense"}
        assert gt["scan"] == Path(rec["scan"]).name and gt["dense"] == Path(rec["dense"]).name
        assert (gt["subject"], gt["expression"], gt["level"], gt["split"]) == (
            raw["subject"], raw["expression"], raw["level"], raw["split"])
        assert gt["units"] == "mm"
        assert list(gt["landmarks"]) == list(LANDMARK_NAMES)
        assert len(gt["ibug68"]) == 68
        assert all(p is None or (len(p) == 3 and all(np.isfinite(p))) for p in gt["ibug68"])
        # the 8 landmarks are the iBUG points of the same names
        for name, k in zip(LANDMARK_NAMES, LANDMARK_IBUG68):
            assert gt["ibug68"][k] == gt["landmarks"][name]
        dense = np.load(rec["dense"])
        assert dense["tri"].dtype == np.int32 and dense["bary"].dtype == np.float32
        assert dense["clean"].dtype == np.float32 and dense["pose"].shape == (3, 4)


def test_cropped_scans_contain_eyes_brows_nose_lips(db):
    """BU-3DFE-like crops: the 8 landmarks and iBUG 17-59 are on every cropped scan; 20-60k vertices."""
    for rec in load_index(db):
        m, gt, _ = _scan(rec)
        missing = [k for k in range(17, 60) if gt["ibug68"][k] is None]
        assert missing == [], (rec["scan"], missing)
        assert 20_000 <= len(m.vertices) <= 60_000


def test_landmarks_on_the_scan_surface(db):
    """On the noise-free surface to JSON/float32 rounding; on the noisy scan within the noise level."""
    for rec in load_index(db):
        m, gt, dense = _scan(rec)
        pts = _gt_points(gt)
        d_clean = distance_to_mesh_reference(pts, dense["clean"].astype(np.float64), m.faces)
        assert d_clean.max() < 2e-3, (rec["scan"], d_clean.max())
        d_noisy = distance_to_mesh_reference(pts, m.vertices, m.faces)
        assert d_noisy.max() < 1.2 and np.median(d_noisy) < 0.3, (rec["scan"], d_noisy.max())
        # the noise itself: sigma 0.1-0.3 mm along the ray, rare spikes of at most 6 mm
        offset = np.linalg.norm(m.vertices - dense["clean"], axis=1)
        assert 0.05 < np.median(offset) < 0.3 and offset.max() <= 6.0 + 5 * 0.3


def test_dense_ground_truth_consistent(db):
    """clean == barycentric combination of the posed deformed ICT triangle (float32 precision)."""
    T = load_ict().triangles
    for rec in load_index(db):
        m, _, dense = _scan(rec)
        tri, bary, clean, pose = dense["tri"], dense["bary"], dense["clean"], dense["pose"]
        assert len(tri) == len(bary) == len(clean) == len(m.vertices)
        assert tri.min() >= 0 and tri.max() < len(T)
        assert bary.min() >= -1e-6 and np.abs(bary.sum(1) - 1).max() < 1e-6
        V, _ = model_vertices(SEED, rec["subject"], rec["expression"], rec["level"])
        R, t = pose[:, :3], pose[:, 3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        ref = np.einsum("sk,skd->sd", bary.astype(np.float64), V[T[tri]]) @ R.T + t
        err = np.abs(ref - clean).max()
        assert err <= 8 * np.finfo(np.float32).eps * np.abs(ref).max(), err


def test_connectivity_unrelated_to_ict(db):
    T = load_ict().triangles
    n_ict = len(load_ict().neutral)
    for rec in load_index(db):
        m, _, dense = _scan(rec)
        assert len(m.vertices) != n_ict
        # scan vertices are grid samples inside ICT triangles, not ICT vertices
        at_vertex = (dense["bary"] > 1 - 1e-5).any(1).mean()
        assert at_vertex < 0.01, at_vertex
        # edges are ~1 mm grid steps, while ICT's face triangles are not a regular grid
        e = m.vertices[m.faces[:, [0, 1, 2]]] - m.vertices[m.faces[:, [1, 2, 0]]]
        assert 0.8 < np.median(np.linalg.norm(e, axis=2)) < 1.6
        # a scan triangle's corners mostly come from different ICT triangles, and no scan
        # triangle is an ICT triangle
        corner_tri = dense["tri"][m.faces]
        assert (corner_tri[:, 0] == corner_tri[:, 1]).mean() < 0.9
        ict_sets = {tuple(sorted(f)) for f in T[np.unique(dense["tri"])].tolist()}
        assert not any(tuple(sorted(f)) in ict_sets for f in m.faces[:200].tolist())


def _bytes(folder: Path, subject: str, stem: str):
    return {ext: (folder / subject / f"{stem}{ext}").read_bytes() for ext in (".ply", ".json", "_dense.npz")}


def test_bitwise_reproducible_and_worker_independent(db, tmp_path):
    # one worker, one scan, other filters: the same bytes as the 2-worker run
    generate(tmp_path / "one", preset="tiny", seed=SEED, workers=1, subjects=1, expressions=["HA"], levels=[4],
             progress=False)
    assert _bytes(tmp_path / "one", "F0001", "F0001_HA04_F3D") == _bytes(db, "F0001", "F0001_HA04_F3D")
    # generate_scan writes the very same scan
    rec = generate_scan(tmp_path / "single", subject="M0001", expression="SU", level=4, seed=SEED)
    assert _bytes(tmp_path / "single", "M0001", "M0001_SU04_F3D") == _bytes(db, "M0001", "M0001_SU04_F3D")
    assert rec["subject"] == "M0001" and rec["split"] == subject_split("M0001")
    assert all(Path(rec[k]).is_absolute() and Path(rec[k]).is_file() for k in ("scan", "gt", "dense"))
    # another seed gives another scan
    generate_scan(tmp_path / "other", subject=1, expression="HA", level=4, seed=SEED + 1)
    assert _bytes(tmp_path / "other", "F0001", "F0001_HA04_F3D")[".ply"] != _bytes(db, "F0001", "F0001_HA04_F3D")[".ply"]


def test_raw_scan_mode(tmp_path):
    """--crop none: head, neck and ears; more vertices; ground truth still on the surface."""
    rec = generate_scan(tmp_path, subject=2, expression="NE", seed=SEED, crop="none")
    assert rec["level"] == 0 and rec["subject"] == "M0001"
    m, gt, dense = _scan(rec)
    assert len(m.vertices) > 40_000
    # the raw scan reaches the ears: wider than the cropped face (~ 150 mm)
    local = (dense["clean"] - dense["pose"][:, 3]) @ dense["pose"][:, :3]  # back to the model frame
    assert np.ptp(local[:, 0]) > 160.0
    d = distance_to_mesh_reference(_gt_points(gt), dense["clean"].astype(np.float64), m.faces)
    assert d.max() < 2e-3


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda out: generate(out, preset="huge"), "unknown preset"),
        (lambda out: generate(out, crop="half"), "unknown crop"),
        (lambda out: generate(out, workers=0), "workers"),
        (lambda out: generate(out, subjects=0), "subjects"),
        (lambda out: generate(out, expressions=["XX"]), "unknown expression"),
        (lambda out: generate(out, levels=[5]), "bad level"),
        (lambda out: generate(out, subset="some"), "unknown subset"),
        (lambda out: generate(out, warp_speed=9), "unknown scanner option"),
        (lambda out: generate_scan(out, subject=0), "bad subject"),
        (lambda out: generate_scan(out, subject="X0001"), "bad subject name"),
        (lambda out: generate_scan(out, expression="LOL"), "unknown expression"),
        (lambda out: generate_scan(out, level=7), "bad level"),
        (lambda out: load_index(out), "no index.json"),
    ],
)
def test_bad_arguments_one_line_error_no_output(tmp_path, call, match):
    out = tmp_path / "out"
    with pytest.raises(FacecorrError, match=match) as ei:
        call(out)
    assert isinstance(ei.value, SynthError) and "\n" not in str(ei.value)
    assert not out.exists()


def test_cli_error_is_one_line(tmp_path, capsys):
    assert synth_main([str(tmp_path / "out"), "--levels", "9", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad level 9" in err
    assert not (tmp_path / "out").exists()


def test_presets_and_filters():
    assert len(scan_list("bu3dfe")) == 2500
    assert len(scan_list("bu3dfe", subset="eval")) == 700
    assert len(scan_list("tiny")) == 50
    assert len(scan_list("tiny", expressions=["NE", "HA"], levels=[2, 4])) == 2 * (1 + 2)
