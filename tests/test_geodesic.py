"""facecorr.geodesic vs references: scipy Dijkstra, exact plane/sphere distances, pygeodesic."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr.geometry.geodesic import GeodesicSolver, distances
from ref_kernels import (
    dijkstra_reference,
    exact_geodesic_reference,
    great_circle,
    grid_mesh,
    ict_face_mesh,
    sphere_mesh,
)


@pytest.fixture(scope="module")
def face():
    V, F = ict_face_mesh()
    return V, F, GeodesicSolver(V, F)


@pytest.fixture(scope="module")
def sphere():
    V, F = sphere_mesh(5, 50.0)
    return V, F, GeodesicSolver(V, F)


def test_dijkstra_matches_scipy(face, sphere):
    for V, F, s in (face, sphere):
        for src in ([0], [5, 1234, len(V) - 1]):
            d = s.distances(src, method="dijkstra")
            ref = dijkstra_reference(V, F, src)
            np.testing.assert_allclose(d, ref, rtol=1e-9, atol=0)


def test_fmm_exact_on_plane_from_vertex_source():
    # on a planar convex grid every straight segment is on the surface: the point-source update
    # reproduces the Euclidean distance (to rounding), also after a rigid motion
    V, F = grid_mesh(40, 30, 0.7)
    src = 15 * 41 + 13
    e = np.linalg.norm(V - V[src], axis=1)
    rng = np.random.default_rng(3)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    for VV in (V, V @ Q.T + [10.0, -20.0, 5.0]):
        d = distances(VV, F, src)
        m = e > 0
        assert d[src] == 0
        np.testing.assert_allclose(d[m], e[m], rtol=1e-9)


def test_fmm_sphere_great_circle(sphere):
    V, F, s = sphere
    assert len(V) == 10242
    errs = []
    for src in (0, 777, 5000):
        d = s.distances(src)
        g = great_circle(V, src, 50.0)
        m = g > 0
        errs.append(np.mean(np.abs(d[m] - g[m]) / g[m]))
    # measured 0.0015 (mean relative); issue target 1%
    assert max(errs) <= 0.0025, errs


def test_fmm_face_vs_exact_pygeodesic(face):
    V, F, s = face
    src = int(np.argmax(V[:, 2]))  # nose tip region
    d = s.distances(src)
    e = exact_geodesic_reference(V, F, src)
    m = np.isfinite(e) & (e > 0) & (e < 1e30)
    rel = np.abs(d[m] - e[m]) / e[m]
    # measured: mean 0.0029, max 0.0141 (6706-vertex ICT narrow face); issue target mean 1%
    assert rel.mean() <= 0.0035, rel.mean()
    assert rel.max() <= 0.02, rel.max()


@pytest.mark.parametrize("method", ["fmm", "dijkstra"])
def test_max_distance_truncation_equals_full(face, method):
    V, F, s = face
    src = [100, 4000]
    full = s.distances(src, method=method)
    part = s.distances(src, max_distance=25.0, method=method)
    inside = full <= 25.0
    assert 100 < inside.sum() < len(V)
    np.testing.assert_array_equal(part[inside], full[inside])
    assert np.isinf(part[~inside]).all()


def test_multi_source_is_nearest_source(face):
    V, F, s = face
    src = [10, 2000, 6000]
    dj = s.distances(src, method="dijkstra")
    np.testing.assert_array_equal(dj, np.min([s.distances(x, method="dijkstra") for x in src], axis=0))
    fm = s.distances(src)
    ref = np.min(s.distance_matrix(src), axis=0)
    # FMM fronts of different sources interact only near the Voronoi boundaries
    assert np.mean(np.abs(fm - ref) / np.maximum(ref, 1.0)) < 1e-3
    assert (fm[src] == 0).all()


def test_distance_matrix_rows(face):
    V, F, s = face
    src = np.array([3, 300, 3000])
    M = s.distance_matrix(src, max_distance=40.0)
    assert M.shape == (3, len(V))
    for row, x in zip(M, src):
        np.testing.assert_array_equal(row, s.distances(x, max_distance=40.0))
    assert s.distance_matrix([], max_distance=1.0).shape == (0, len(V))


def test_unreached_component_is_inf():
    V, F = grid_mesh(5, 5, 1.0)
    V2 = np.concatenate([V, V + [100.0, 0, 0]])
    F2 = np.concatenate([F, F + len(V)])
    for method in ("fmm", "dijkstra"):
        d = distances(V2, F2, 0, method=method)
        assert np.isfinite(d[: len(V)]).all() and np.isinf(d[len(V):]).all()
    # an isolated vertex (in no face) is unreachable too
    V3 = np.concatenate([V, [[50.0, 50.0, 0.0]]])
    assert np.isinf(distances(V3, F, 0)[-1])


def test_obtuse_triangles_split_and_exact():
    # a lattice of flat triangles (about 147 degree angles): without the unfolding split the
    # updates fall back to edges; with it, a planar point source is still reproduced exactly
    nx, ny = 30, 30
    j, i = np.mgrid[0 : ny + 1, 0 : nx + 1]
    V = np.stack([i + 0.5 * (j % 2), 0.15 * j, 0 * i], -1).reshape(-1, 3).astype(float)
    ids = lambda i, j: j * (nx + 1) + i  # noqa: E731
    F = []
    for jj in range(ny):
        for ii in range(nx):
            if jj % 2 == 0:
                F += [[ids(ii, jj), ids(ii + 1, jj), ids(ii, jj + 1)], [ids(ii + 1, jj), ids(ii + 1, jj + 1), ids(ii, jj + 1)]]
            else:
                F += [[ids(ii, jj), ids(ii + 1, jj + 1), ids(ii, jj + 1)], [ids(ii, jj), ids(ii + 1, jj), ids(ii + 1, jj + 1)]]
    s = GeodesicSolver(V, np.array(F))
    assert s.n_obtuse_split > 0
    c = ids(15, 16)
    e = np.linalg.norm(V - V[c], axis=1)
    d = s.distances(c)
    m = e > 0
    np.testing.assert_allclose(d[m], e[m], rtol=1e-9)
    assert np.mean(np.abs(s.distances(c, method="dijkstra")[m] - e[m]) / e[m]) > 0.01


BAD = [
    (lambda V, F: (V[:, :2], F), {}, "shape"),
    (lambda V, F: (np.where(np.arange(len(V))[:, None] == 3, np.nan, V), F), {}, "NaN"),
    (lambda V, F: (V, F[:, :2]), {}, "shape"),
    (lambda V, F: (V, F + len(V)), {}, "out of range"),
    (lambda V, F: (V, -F - 1), {}, "out of range"),
    (lambda V, F: (V, F[:0]), {}, "no faces"),
    (lambda V, F: (V[:0], F[:0]), {}, "no vertices"),
    (lambda V, F: (V, F.astype(float) + 0.5), {}, "integer"),
]


@pytest.mark.parametrize("make, kw, msg", BAD)
def test_bad_mesh(make, kw, msg):
    V, F = grid_mesh(3, 3, 1.0)
    VV, FF = make(V, F)
    with pytest.raises(ValueError, match=msg) as e:
        distances(VV, FF, 0, **kw)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "sources, kw, msg",
    [
        ([16], {}, "out of range"),
        ([-1], {}, "out of range"),
        ([], {}, "empty"),
        ([0.5], {}, "integer"),
        ([0], {"method": "heat"}, "method"),
        ([0], {"max_distance": -1.0}, "max_distance"),
        ([0], {"max_distance": float("nan")}, "max_distance"),
        ([[0, 1]], {}, "1-D"),
    ],
)
def test_bad_query(sources, kw, msg):
    V, F = grid_mesh(3, 3, 1.0)
    s = GeodesicSolver(V, F)
    with pytest.raises(ValueError, match=msg):
        s.distances(sources, **kw)


# ---- properties (hypothesis) on the ICT face region ----------------------------------------

_face_cache = {}


def _face():
    if "s" not in _face_cache:
        V, F = ict_face_mesh()
        _face_cache["s"] = (V, F, GeodesicSolver(V, F))
    return _face_cache["s"]


vertex = st.integers(0, 6705)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), src=vertex)
def test_property_renumbering_invariance(seed, src):
    V, F, s = _face()
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(V))  # new index -> old index
    inv = np.argsort(perm)
    F2 = inv[F][:, rng.permutation(3)][rng.permutation(len(F))]
    d2 = distances(V[perm], F2, inv[src])
    np.testing.assert_allclose(d2[inv], s.distances(src), rtol=1e-9, atol=1e-9)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), src=vertex)
def test_property_rigid_motion_invariance(seed, src):
    V, F, s = _face()
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    t = rng.normal(size=3) * 100
    d2 = distances(V @ Q.T + t, F, src)
    np.testing.assert_allclose(d2, s.distances(src), rtol=1e-9, atol=1e-9)


@settings(max_examples=15, deadline=None)
@given(a=vertex, b=vertex, c=vertex)
def test_property_symmetry_and_triangle_inequality(a, b, c):
    V, F, s = _face()
    D = s.distance_matrix([a, b, c])
    # FMM is a discretisation: symmetric and metric up to its error (max 1.4% vs exact here)
    tol = lambda x: 0.03 * x + 0.05  # noqa: E731
    assert abs(D[0, b] - D[1, a]) <= tol(max(D[0, b], D[1, a]))
    assert D[0, c] <= D[0, b] + D[1, c] + tol(D[0, c])
    # Dijkstra is an exact graph metric
    Dd = s.distance_matrix([a, b, c], method="dijkstra")
    assert abs(Dd[0, b] - Dd[1, a]) <= 1e-9 * max(1.0, Dd[0, b])
    assert Dd[0, c] <= Dd[0, b] + Dd[1, c] + 1e-9
