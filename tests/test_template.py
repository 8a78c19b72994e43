"""Invariants of the packaged blendshape template (facecorr.template) and its CLI."""

import json

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from facecorr import cli, names
from facecorr.geometry.raster import rasterize
from facecorr.geometry.transforms import view_rotation
from facecorr.template import (
    BOUNDARY_LOOP_NAMES, ICT_MODEL_PATH, MAX_BLENDSHAPE_COSINE, MIN_BLENDSHAPE_COSINE, PEEL_RINGS,
    REGION_NAMES, TEMPLATE_PATH, build_template, load_template, template_from_arrays, visible_points,
)


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
            assert np.array_equal(a[k], packaged[k]), f"{k}: rebuild with python -m facecorr.template.build"
    assert template_from_arrays(a).n_vertices == t.n_vertices


def test_cli_json_and_png(tmp_path, capsys):
    assert cli.main(["template", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    t = load_template()
    assert out["n_vertices"] == t.n_vertices
    assert len(out["ibug68"]) == 68 and out["ibug68"][36] == int(t.ibug68[36])
    assert out["landmarks"] == t.landmarks
    assert {k: v["count"] for k, v in out["regions"].items()} == {
        n: len(t.region_ids(n)) for n in REGION_NAMES}
    assert sum(v["count"] for v in out["regions"].values()) == t.n_vertices
    png = tmp_path / "sub" / "t.png"
    assert cli.main(["template", "--png", str(png), "--json", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text()) == out
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["sub", "t.json", "t.png"]  # no temp files
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 50_000


def test_cli_bad_input(tmp_path, capsys):
    for argv in (["template"], ["template", "--json", str(tmp_path / "t.json"), "--png", str(tmp_path / "x.jpg")]):
        capsys.readouterr()
        assert cli.main(argv) == 2, argv  # a user's mistake: one line, exit 2
        err = capsys.readouterr().err
        assert err.startswith("facecorr: error:") and err.count("\n") == 1, err
    assert not list(tmp_path.iterdir())


def test_visible_points_depth_test():
    # a square in the z = 0 plane facing +z; points above it are seen, below it hidden
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    pts = np.array([[0, 0, 1.0], [0, 0, -1.0], [0.2, 0.3, 0.0], [5, 5, -3.0]])
    np.testing.assert_array_equal(visible_points(v, f, pts, np.eye(3)), [True, False, True, True])
    # seen from behind (yaw 180 deg) it is the other way round
    r = np.diag([-1.0, 1.0, -1.0])
    np.testing.assert_array_equal(visible_points(v, f, pts, r), [False, True, True, True])


def _grid_sheet(nx, ny, x0, y0, step, z):
    """A triangulated (ny, nx) grid sheet: vertices (nx * ny, 3) at heights z(x, y), faces (F, 3)."""
    x, y = np.meshgrid(x0 + step * np.arange(nx), y0 + step * np.arange(ny))
    v = np.stack([x.ravel(), y.ravel(), z(x, y).ravel()], axis=1)
    i = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_visible_points_agrees_with_the_depth_buffer():
    """visible_points against the compiled z-buffer at pixel centres, where the buffer's depth is
    exact: two overlapping wavy sheets seen from an oblique view, points at random depths."""
    v1, f1 = _grid_sheet(23, 19, -10.3, -8.7, 0.93, lambda x, y: 2 * np.sin(0.4 * x) * np.cos(0.3 * y))
    v2, f2 = _grid_sheet(17, 17, -3.1, -5.2, 0.71, lambda x, y: 3 + 0.2 * x - 0.1 * y)
    v, f = np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)])
    r = view_rotation(25, -10)
    vr = v @ r.T
    px, lo = 0.25, np.floor(vr[:, :2].min(0)) - 1  # pixel size and image origin, mm
    w, h = (np.ceil((vr[:, :2].max(0) - lo) / px) + 2).astype(int)
    _, _, zbuf = rasterize((vr[:, :2] - lo) / px, -vr[:, 2], f, w, h)  # depth = -z
    rng = np.random.default_rng(3)
    rows, cols = np.nonzero(np.isfinite(zbuf))
    pick = rng.choice(len(rows), 400, replace=False)
    top = -zbuf[rows[pick], cols[pick]]  # z of the nearest surface at the pixel centre, view frame
    z = top + rng.uniform(-4, 2, len(pick))
    keep = np.abs(z + 0.5 - top) > 1e-6  # no exact ties with tol = 0.5
    q_view = np.stack([lo[0] + px * cols[pick], lo[1] + px * rows[pick], z], axis=1)[keep]
    points = q_view @ r  # back to model coordinates (r is orthonormal)
    expected = top[keep] <= z[keep] + 0.5
    assert 50 < expected.sum() < len(expected) - 50  # both outcomes are exercised
    np.testing.assert_array_equal(visible_points(v, f, points, r, tol=0.5), expected)


def _seen_by_depth_buffer(vertices, faces, px=0.25, min_cos=0.17):
    """(N,) bool: the vertex is a corner of a triangle that is the nearest surface at some pixel of
    an orthographic z-buffer (``px`` mm pixels) and faces that view (cos > min_cos), in one of
    the scanner views (yaw -60..60 deg in 30 deg steps, pitch 0 and 15 deg from below)."""
    seen = np.zeros(len(vertices), bool)
    for yaw in (-60, -30, 0, 30, 60):
        for pitch in (0, -15):
            v = vertices @ view_rotation(yaw, pitch).T
            lo = v[:, :2].min(0) - 1
            w, h = np.ceil((v[:, :2].max(0) + 1 - lo) / px).astype(int) + 1
            tri, _, _ = rasterize((v[:, :2] - lo) / px, -v[:, 2], faces, w, h)
            a, b, c = (v[faces[:, k]] for k in range(3))
            n = np.cross(b - a, c - a)
            win = np.unique(tri[tri >= 0])
            win = win[n[win, 2] > min_cos * np.linalg.norm(n[win], axis=1)]
            seen[faces[win].ravel()] = True
    return seen


def test_template_is_what_scanners_see(t, ict):
    """Every template vertex around the nose is the nearest surface, facing the view, somewhere
    in a scanner's depth buffer (the compiled rasterizer, not the builder's per-point rule): the
    nostril tubes are gone. The same check on the ICT narrow face cut without the nostril step
    finds the tubes (it can fail)."""
    from facecorr.template.build import _rings_from_outer_boundary

    def nose(v):
        return (np.abs(v[:, 0]) < 20) & (np.abs(v[:, 1]) < 15)

    seen = _seen_by_depth_buffer(t.vertices, t.faces)
    ids = np.flatnonzero(nose(t.vertices))
    assert len(ids) > 500 and seen[ids].all(), ids[~seen[ids]]

    v, tris = ict["neutral"].astype(np.float64), ict["triangles"].astype(np.int64)
    with np.load(ICT_MODEL_PATH) as d:
        inside = d["narrow_face"].astype(bool)
    inside &= _rings_from_outer_boundary(tris[inside[tris].all(axis=1)], len(v)) >= PEEL_RINGS
    faces = tris[inside[tris].all(axis=1)]
    unseen = np.flatnonzero(nose(v) & np.isin(np.arange(len(v)), faces) & ~_seen_by_depth_buffer(v, faces))
    assert len(unseen) > 100  # the two nostril tubes (2 x 138 vertices), mostly out of sight
    assert not np.isin(unseen, t.ict_vertex).any()  # and the template dropped every one of them
