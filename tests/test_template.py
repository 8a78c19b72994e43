"""Invariants of the packaged blendshape template (facecorr.template) and its CLI."""

import argparse
import json

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from facecorr import names
from facecorr.template import (
    BOUNDARY_LOOP_NAMES, ICT_MODEL_PATH, MAX_BLENDSHAPE_COSINE, MIN_BLENDSHAPE_COSINE, REGION_NAMES, TEMPLATE_PATH, build_template,
    load_template, template_from_arrays,
)


@pytest.fixture(scope="module")
def t():
    return load_template()


@pytest.fixture(scope="module")
def ict():
    with np.load(ICT_MODEL_PATH) as d:
        return {k: d[k] for k in ("neutral", "triangles", "part_id", "part_names", "landmarks68",
                                  "expression", "expression_names")}


def _adjacency(n, faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return (a + a.T).tocsr()


def _n_components(adj, ids):
    return connected_components(adj[ids][:, ids], directed=False)[0]


def test_sizes_and_types(t):
    n, m, k = t.n_vertices, len(t.faces), t.n_blendshapes
    assert 5000 <= n <= 10000
    assert t.vertices.shape == (n, 3) and t.faces.shape == (m, 3)
    assert 8 <= k <= 15
    assert t.blendshapes.shape == (k, n, 3) and len(t.blendshape_names) == k
    assert len(set(t.blendshape_names)) == k
    assert t.regions.shape == (n,) and set(np.unique(t.regions)) == {0, 1, 2}
    assert t.landmark_ids.shape == (8,) and t.ibug68.shape == (68,)
    assert t.graph_points.shape == (8, 3) and t.graph_edges.shape[1] == 2
    assert t.faces.min() == 0 and t.faces.max() == n - 1  # no unused vertex
    assert TEMPLATE_PATH.stat().st_size < 2_000_000  # small package data


def test_one_piece_manifold_with_six_loops(t):
    adj = _adjacency(t.n_vertices, t.faces)
    assert _n_components(adj, np.arange(t.n_vertices)) == 1
    e = np.sort(np.concatenate([t.faces[:, [0, 1]], t.faces[:, [1, 2]], t.faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert counts.max() == 2  # edge-manifold
    assert tuple(t.boundary_loops) == BOUNDARY_LOOP_NAMES
    x = t.vertices[:, 0]
    for side, sign in (("right", -1), ("left", 1)):  # loops named by the right side
        for what in ("eye", "nostril"):
            assert sign * x[t.boundary_loops[f"{side}_{what}"]].mean() > 3
    assert sum(len(l) for l in t.boundary_loops.values()) == len(t.boundary) == (counts == 1).sum()
    for name, loop in t.boundary_loops.items():  # consecutive loop vertices share an edge
        assert adj[loop, np.roll(loop, -1)].min() > 0, name
    # a clean outer crop line: no notches or spikes (turn between consecutive boundary edges)
    p = t.vertices[t.boundary_loops["outer"]]
    d1, d0 = np.roll(p, -1, axis=0) - p, p - np.roll(p, 1, axis=0)
    cos_turn = (d1 * d0).sum(1) / np.linalg.norm(d1, axis=1) / np.linalg.norm(d0, axis=1)
    assert cos_turn.min() > np.cos(np.radians(20))
    # the mouth slit is open between the lips: its loop reaches the inner lip corners (iBUG 60,
    # 64) and stays inside the outer ones (48, 54)
    mx = t.vertices[t.boundary_loops["mouth"], 0]
    x = t.vertices[t.ibug68, 0]
    assert x[48] <= mx.min() <= x[60] and x[64] <= mx.max() <= x[54]


def test_only_face_part_no_ears_neck_mouth_interior(t, ict):
    parts = list(ict["part_names"])
    assert (ict["part_id"][t.ict_vertex] == parts.index("face")).all()
    assert np.array_equal(t.vertices, ict["neutral"][t.ict_vertex].astype(np.float64))
    # ears stick out beyond |x| ~ 75 mm at the side of the head: the template stays inside
    assert np.abs(t.vertices[:, 0]).max() < 80


def test_ict_face_map_is_exact(t, ict):
    fm = t.ict_face_to_template_face
    assert fm.shape == (len(ict["triangles"]),)
    kept = np.flatnonzero(fm >= 0)
    assert len(kept) == len(t.faces)
    assert np.array_equal(np.sort(fm[kept]), np.arange(len(t.faces)))
    # the same corners, in the same order: barycentric coordinates carry over unchanged
    assert np.array_equal(t.ict_vertex[t.faces[fm[kept]]], ict["triangles"][kept])


def test_landmarks_and_sides(t, ict):
    assert np.array_equal(t.ibug68[t.ibug68 >= 0], np.searchsorted(t.ict_vertex, ict["landmarks68"][t.ibug68 >= 0]))
    assert np.array_equal(t.landmark_ids, t.ibug68[list(names.LANDMARK_IBUG68)])
    assert (t.ibug68[17:] >= 0).all()  # every evaluation point (17-59) and the inner lips
    # every landmark and evaluation point has template around it (not on the crop line)
    assert not np.isin(t.ibug68[17:48], t.boundary_loops["outer"]).any()
    assert list(t.landmarks) == list(names.LANDMARK_NAMES)
    x = t.vertices[:, 0]
    assert x[t.ibug68[36]] < 0 < x[t.ibug68[45]]  # subject's right at -x
    for name, vid in t.landmarks.items():
        if name.startswith("right_"):
            assert x[vid] < -5
        elif name.startswith("left_"):
            assert x[vid] > 5
        else:
            assert abs(x[vid]) < 1.0
    # names.IBUG68_REGIONS sides: right regions at -x, left at +x
    for region, pts in names.IBUG68_REGIONS.items():
        mean_x = x[t.ibug68[list(pts)]].mean()
        if region.startswith("right_"):
            assert mean_x < -10, region
        elif region.startswith("left_"):
            assert mean_x > 10, region
    # nose tip is the most forward landmark, eyes above the nose
    p = t.graph_points
    assert np.argmax(p[:, 2]) == names.LANDMARK_NAMES.index("nose_tip")
    assert p[:4, 1].min() > p[4:, 1].max()
    np.testing.assert_array_equal(t.graph_points, t.vertices[t.landmark_ids])


def test_landmark_graph(t):
    e = t.graph_edges
    assert e.min() >= 0 and e.max() < 8 and (e[:, 0] != e[:, 1]).all()
    assert len({tuple(sorted(x)) for x in e.tolist()}) == len(e)
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(8, 8))
    assert connected_components(g, directed=False)[0] == 1
    # nose points are connected to each other and each eye corner reaches a nose point
    nose = {4, 5, 6, 7}
    pairs = {tuple(sorted(x)) for x in e.tolist()}
    assert {(4, 6), (5, 6), (6, 7)} <= pairs
    for eye in range(4):
        assert any((min(eye, n), max(eye, n)) in pairs for n in nose)


def test_regions_nonempty_contiguous_and_placed(t):
    adj = _adjacency(t.n_vertices, t.faces)
    y = t.vertices[:, 1]
    for r, name in enumerate(REGION_NAMES):
        ids = t.region_ids(name)
        assert len(ids) > 100, name
        assert _n_components(adj, ids) == 1, name
    lips = t.ibug68[48:68]
    assert (t.regions[lips] == REGION_NAMES.index("mouth")).all()
    assert (t.regions[t.landmark_ids] == REGION_NAMES.index("upper")).all()
    assert t.regions[t.ibug68[8]] == REGION_NAMES.index("chin")  # the chin point of the jaw line
    assert y[t.region_ids("chin")].max() < y[t.ibug68[57]]  # chin below the lower lip
    assert y[t.region_ids("mouth")].max() < y[t.ibug68[33]]  # mouth below the subnasal point


def test_blendshapes_not_redundant_and_local(t):
    d = t.blendshapes.reshape(t.n_blendshapes, -1)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cos = d @ d.T
    np.testing.assert_allclose(cos, t.blendshape_cosine, atol=1e-5)
    off = cos[~np.eye(len(cos), dtype=bool)]
    assert MIN_BLENDSHAPE_COSINE < off.min() and off.max() < MAX_BLENDSHAPE_COSINE
    for k, name in enumerate(t.blendshape_names):
        mag = np.linalg.norm(t.blendshapes[k], axis=1)
        assert mag.max() > 3.0, name  # a real motion, mm
        # left/right shapes act on their side
        if name.endswith("_L"):
            assert np.average(t.vertices[:, 0], weights=mag) > 5, name
        if name.endswith("_R"):
            assert np.average(t.vertices[:, 0], weights=mag) < -5, name
    jaw = t.blendshapes[list(t.blendshape_names).index("jawOpen")]
    assert jaw[t.ibug68[8], 1] < -10  # jawOpen lowers the chin


def test_expression(t):
    alpha = np.zeros(t.n_blendshapes)
    np.testing.assert_array_equal(t.expression(alpha), t.vertices)
    alpha[0], alpha[3] = 0.5, 1.0
    np.testing.assert_allclose(t.expression(alpha), t.vertices + 0.5 * t.blendshapes[0] + t.blendshapes[3])
    with pytest.raises(ValueError):
        t.expression(np.zeros(t.n_blendshapes + 1))
    with pytest.raises(ValueError):
        t.expression(np.full(t.n_blendshapes, np.nan))
    assert not t.vertices.flags.writeable  # the cached template cannot be changed by accident


def test_build_is_deterministic_and_matches_packaged_file(t):
    a, b = build_template(), build_template()
    assert a.keys() == b.keys()
    with np.load(TEMPLATE_PATH) as packaged:
        assert set(packaged.files) == set(a)
        for k in a:
            assert np.array_equal(a[k], b[k]), k
            assert np.array_equal(a[k], packaged[k]), f"{k}: rebuild with python -m facecorr.template --build"
    assert template_from_arrays(a).n_vertices == t.n_vertices


def test_cli_json_and_png(tmp_path, capsys):
    from facecorr.cli.template import add_commands

    parser = argparse.ArgumentParser()
    add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["template", "--json"])
    assert args.func(args) == 0
    out = json.loads(capsys.readouterr().out)
    t = load_template()
    assert out["n_vertices"] == t.n_vertices
    assert len(out["ibug68"]) == 68 and out["ibug68"][36] == int(t.ibug68[36])
    assert out["landmarks"] == t.landmarks
    assert {k: v["count"] for k, v in out["regions"].items()} == {
        n: len(t.region_ids(n)) for n in REGION_NAMES}
    assert sum(v["count"] for v in out["regions"].values()) == t.n_vertices
    png = tmp_path / "sub" / "t.png"
    args = parser.parse_args(["template", "--png", str(png), "--json", str(tmp_path / "t.json")])
    assert args.func(args) == 0
    assert json.loads((tmp_path / "t.json").read_text()) == out
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["sub", "t.json", "t.png"]  # no temp files
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 50_000


def test_cli_bad_input(tmp_path):
    from facecorr.errors import FacecorrError
    from facecorr.cli.template import add_commands

    parser = argparse.ArgumentParser()
    add_commands(parser.add_subparsers(dest="command"))
    for argv in (["template"], ["template", "--json", str(tmp_path / "t.json"), "--png", str(tmp_path / "x.jpg")]):
        args = parser.parse_args(argv)
        with pytest.raises(FacecorrError):
            args.func(args)
    assert not list(tmp_path.iterdir())


def test_visible_points_depth_test():
    from facecorr.cli.template import visible_points

    # a square in the z = 0 plane facing +z; points above it are seen, below it hidden
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    pts = np.array([[0, 0, 1.0], [0, 0, -1.0], [0.2, 0.3, 0.0], [5, 5, -3.0]])
    np.testing.assert_array_equal(visible_points(v, f, pts, np.eye(3)), [True, False, True, True])
    # seen from behind (yaw 180 deg) it is the other way round
    r = np.diag([-1.0, 1.0, -1.0])
    np.testing.assert_array_equal(visible_points(v, f, pts, r), [False, True, True, True])


def test_template_is_what_scanners_see():
    """Every template vertex outside the eye/mouth openings' rims faces some scanner view: the
    nostril tubes are gone (a face cut from the ICT head without them would fail this)."""
    from facecorr.geometry.transforms import view_rotation
    from facecorr.template import visible_points

    t = load_template()
    nose = (np.abs(t.vertices[:, 0]) < 20) & (np.abs(t.vertices[:, 1]) < 15)
    ids = np.flatnonzero(nose)
    normals = t.mesh().vertex_normals
    seen = np.zeros(len(ids), bool)
    for yaw in (-60, -30, 0, 30, 60):
        for pitch in (0, -15):
            r = view_rotation(yaw, pitch)
            seen |= ((normals[ids] @ r.T)[:, 2] > 0.17) & visible_points(t.vertices, t.faces, t.vertices[ids], r)
    assert seen.mean() > 0.98, ids[~seen]
