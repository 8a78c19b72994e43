"""The Rust closest-point kernel (``_core.Surface``, ``Mesh.surface``) and the continuous match
weights (issue 13, #15), against plain numpy references: the closest point over *every* triangle
(``closest_points_on_triangles``), barycentric interpolation of the normals and boundary flags,
and ``geometry.closest.match_weights``."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr import _core
from facecorr.geometry.closest import closest_points_on_triangles, match_weights, smoothstep
from facecorr.geometry.mesh import Mesh


def bumpy_grid(n=24, h=1.0, seed=0):
    """A wavy, slightly irregular grid surface (n x n vertices, spacing ~h mm)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h)
    x = x + rng.uniform(-0.2, 0.2, x.shape) * h
    y = y + rng.uniform(-0.2, 0.2, y.shape) * h
    z = 3.0 * np.sin(x / 5.0) * np.cos(y / 7.0)
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    i = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    return v, f


def brute_force(v, f, q):
    """Closest point over every triangle: (face, bary, dist) per query (numpy)."""
    qq = np.repeat(q, len(f), axis=0)
    tri = np.tile(f, (len(q), 1))
    bary, d = closest_points_on_triangles(qq, v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]])
    d = d.reshape(len(q), len(f))
    best = d.argmin(axis=1)
    return best, bary.reshape(len(q), len(f), 3)[np.arange(len(q)), best], d.min(axis=1)


@pytest.mark.parametrize("k", [1, 3])
def test_closest_points_match_every_triangle(k):
    v, f = bumpy_grid()
    mesh = Mesh(v, f)
    rng = np.random.default_rng(1)
    q = np.column_stack([rng.uniform(3, 20, 400), rng.uniform(3, 20, 400), rng.uniform(-5, 5, 400)])
    face, bary, point, dist, normal, bshare = mesh.surface.closest(q, k)
    _, _, d_ref = brute_force(v, f, q)
    np.testing.assert_allclose(dist, d_ref, atol=1e-9)
    # the point is the barycentric combination and lies at that distance
    np.testing.assert_allclose(point, np.einsum("qk,qkd->qd", bary, v[f[face]]), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(q - point, axis=1), dist, atol=1e-9)
    # normal = normalised barycentric mix of the vertex normals; boundary share likewise
    n_ref = np.einsum("qk,qkd->qd", bary, mesh.vertex_normals[f[face]])
    np.testing.assert_allclose(normal, n_ref / np.linalg.norm(n_ref, axis=1, keepdims=True), atol=1e-9)
    np.testing.assert_allclose(bshare, np.einsum("qk,qk->q", bary, mesh.is_boundary[f[face]].astype(float)), atol=1e-12)


def test_nearest_vertex_mode_and_boundary_share():
    v, f = bumpy_grid(10)
    mesh = Mesh(v, f)
    q = v[[0, 55]] + np.array([0.0, 0.0, 0.3])
    face, _, point, dist, normal, bshare = mesh.surface.closest(q, 0)
    assert (face == -1).all()
    d, i = mesh.kdtree.query(q)
    np.testing.assert_allclose(point, v[np.asarray(i).ravel()])
    np.testing.assert_allclose(dist, np.asarray(d).ravel())
    assert bshare[0] == 1.0 and bshare[1] == 0.0  # vertex 0 is a corner, 55 inside
    # beyond the grid's edge the closest point is on a boundary edge: share 1
    _, _, _, _, _, b = mesh.surface.closest(np.array([[-3.0, 4.0, 0.0]]), 3)
    assert b[0] == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.floats(1e-7, 1e-3))
def test_closest_point_moves_continuously(seed, eps):
    """A query moved by eps: its distance to the surface changes by at most eps (exactly
    1-Lipschitz), and its closest point by about eps, except across the bisector of a concave
    crease, where it may hop between the two faces by at most ~2 d sin(θ/2) (d the distance, θ
    the crease's bend: a few degrees here). Nearest-vertex matches hop by a whole edge (~1 mm)."""
    v, f = bumpy_grid(16, seed=seed % 7)
    s = Mesh(v, f).surface
    rng = np.random.default_rng(seed)
    q = np.column_stack([rng.uniform(3, 12, 50), rng.uniform(3, 12, 50), np.zeros(50)])
    q[:, 2] = 3.0 * np.sin(q[:, 0] / 5.0) * np.cos(q[:, 1] / 7.0) + rng.uniform(-1, 1, 50)
    dq = rng.normal(size=(50, 3))
    dq *= eps / np.linalg.norm(dq, axis=1, keepdims=True)
    _, _, p0, d0, _, _ = s.closest(q, 3)
    _, _, p1, d1, _, _ = s.closest(q + dq, 3)
    assert np.abs(d1 - d0).max() <= eps * (1 + 1e-9) + 1e-12
    assert (np.linalg.norm(p1 - p0, axis=1) <= 1.5 * eps + 0.2 * d0 + 1e-12).all()
    nv = s.closest(q, 0)[2]
    assert np.linalg.norm(nv - p0, axis=1).max() > 10 * eps  # the nearest vertex is elsewhere


def test_bad_input():
    v, f = bumpy_grid(5)
    with pytest.raises(ValueError, match="faces"):
        _core.Surface(v, f + 100, v, np.zeros(len(v), bool))
    with pytest.raises(ValueError, match="NaN"):
        Mesh(v, f).surface.closest(np.array([[np.nan, 0, 0]]), 3)
    with pytest.raises(ValueError, match="k must be"):
        Mesh(v, f).surface.closest(np.zeros((1, 3)), 17)


def test_match_weights_ramps():
    c80 = np.cos(np.radians(80.0))
    w = match_weights(np.array([1.0, -0.5, 1.0, 1.0, 1.0, c80]), np.array([0, 0, 6, 4.5, 0, 0.0]),
                      np.array([0, 0, 0, 0, 0.25, 0]), 80.0, 10.0, 5.0, 1.0)
    np.testing.assert_allclose(w[:5], [1.0, 0.0, 0.0, 0.5, 0.75], atol=1e-12)
    assert abs(w[5] - 0.5) < 0.05
    # bands of 0: the hard tests (the paper's)
    hard = match_weights(np.array([c80 + 1e-9, c80 - 1e-9]), np.array([4.9, 1.0]), np.zeros(2), 80.0, 0.0, 5.0, 0.0)
    np.testing.assert_array_equal(hard, [1.0, 0.0])
    # per-match angles broadcast; continuity: a tiny change of the inputs changes the weight a little
    x = np.linspace(-1, 1, 2001)
    wx = match_weights(x, np.zeros_like(x), np.zeros_like(x), 40.0, 10.0, np.inf, 1.0)
    assert np.abs(np.diff(wx)).max() < 0.01
    np.testing.assert_allclose(smoothstep(0.0, 1.0, np.array([-1, 0, 0.5, 1, 2.0])), [0, 0, 0.5, 1, 1])


def test_shape_fit_weights_agree_with_the_numpy_weights():
    """The Rust shape fit's first correspondences weigh as the numpy reference says (closest
    points + match_weights with the fit's options), counted through the solve's n_valid."""
    from facecorr.geometry.mesh import vertex_normals
    from facecorr.registration.shape import fit_shape

    v, f = bumpy_grid(12)
    mesh = Mesh(v, f)
    rng = np.random.default_rng(3)
    moved = v + mesh.vertex_normals * rng.uniform(-5.5, 5.5, (len(v), 1))  # some beyond the 4-5 mm ramp
    res = fit_shape(moved, f, mesh, n_levels=1, max_icp=1, max_iter=1)
    _, _, _, dist, normal, bshare = mesh.surface.closest(moved, 3)
    cos = np.einsum("ij,ij->i", vertex_normals(moved, f), normal)
    w = match_weights(cos, dist, bshare, 80.0, 10.0, 5.0, 1.0)
    assert 0 < res.solves[0]["n_valid"] == int((w > 0).sum()) < len(v)


def test_a_surface_on_the_meshs_kdtree_answers_as_one_with_its_own():
    """Mesh.surface shares Mesh.kdtree's tree (built once per scan): the same closest points as a
    Surface that builds its own, and a tree over other points is refused."""
    v, f = bumpy_grid()
    mesh = Mesh(v, f)
    f64 = np.ascontiguousarray(f, dtype=np.int64)
    own = _core.Surface(v, f64, mesh.vertex_normals, mesh.is_boundary)
    q = np.random.default_rng(3).uniform(-2, 25, (300, 3))
    for k in (0, 1, 3):
        for a, b in zip(own.closest(q, k), mesh.surface.closest(q, k)):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="not over these vertices"):
        _core.Surface(v + 1.0, f64, mesh.vertex_normals, mesh.is_boundary, mesh.kdtree._tree)
