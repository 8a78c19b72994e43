"""SMACOF, out-of-sample placement and canonical forms (isometric bending)."""

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from facecorr.geometry.transforms import kabsch
from facecorr.landmarks.paper.mds import canonical_form, classical_mds, farthest_point_sample, place_out_of_sample, smacof, stress


def _grid(nu=41, nv=21, width=120.0, height=60.0):
    u, v = np.meshgrid(np.linspace(0, width, nu), np.linspace(0, height, nv), indexing="ij")
    uv = np.column_stack([u.ravel(), v.ravel()])
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return uv, faces


def _graph_distances(v, faces):
    """Reference geodesics: Dijkstra on the triangle edges plus the face diagonals (good enough
    to compare two isometric meshes with the same connectivity)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    w = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    g = coo_matrix((w, (e[:, 0], e[:, 1])), shape=(len(v), len(v))).tocsr()

    def rows(sources):
        return dijkstra(g, directed=False, indices=sources)
    return rows


def test_classical_mds_recovers_euclidean_configuration():
    x = np.random.default_rng(0).normal(size=(30, 3)) * 10
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)
    y = classical_mds(d)
    np.testing.assert_allclose(np.linalg.norm(y[:, None] - y[None], axis=-1), d, atol=1e-8)


@pytest.mark.parametrize("seed", range(5))
def test_smacof_stress_decreases_monotonically(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(40, 5)) * 10  # 5-D data, embedded in 3-D: positive residual stress
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)
    y, hist = smacof(d, 3, init=rng.normal(size=(40, 3)), max_iter=200, rel_tol=0)
    assert len(hist) == 201
    assert (np.diff(hist) <= 1e-9 * hist[0]).all()
    assert hist[-1] < 0.5 * hist[0]
    assert stress(y, d) == pytest.approx(hist[-1])


def test_smacof_exact_on_euclidean_data():
    x = np.random.default_rng(1).normal(size=(25, 3)) * 10
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)
    y, hist = smacof(d, 3, init=np.random.default_rng(2).normal(size=(25, 3)), max_iter=2000, rel_tol=1e-12)
    assert hist[-1] < 1e-6 * np.sum(d**2)


def test_out_of_sample_exact_on_euclidean_data():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(20, 3)) * 10
    q = rng.normal(size=(50, 3)) * 12
    d_q = np.linalg.norm(q[:, None] - x[None], axis=-1)
    np.testing.assert_allclose(place_out_of_sample(x, d_q, iters=0), q, atol=1e-8)  # LMDS alone is exact
    np.testing.assert_allclose(place_out_of_sample(x, d_q, iters=10), q, atol=1e-6)


def test_farthest_point_sample_spreads():
    p = np.random.default_rng(0).uniform(size=(2000, 3))
    idx = farthest_point_sample(p, 50, start=7)
    assert idx[0] == 7 and len(set(idx)) == 50
    # covering radius of 50 FPS points in the unit cube is far below a random choice's
    rnd = np.random.default_rng(1).choice(2000, 50, replace=False)

    def cover(s):
        return np.min(np.linalg.norm(p[:, None] - p[s][None], axis=-1), axis=1).max()
    assert cover(idx) < 0.8 * cover(rnd)


def test_isometric_bend_leaves_canonical_form_unchanged():
    uv, faces = _grid()
    flat = np.column_stack([uv, np.zeros(len(uv))])
    radius = 120.0 / np.pi  # the 120 mm wide grid becomes a half cylinder
    ang = uv[:, 0] / radius
    rolled = np.column_stack([radius * np.sin(ang), uv[:, 1], radius * np.cos(ang)])
    query = np.arange(0, len(uv), 7)
    cf_flat = canonical_form(flat, _graph_distances(flat, faces), query, n_samples=60, seed_vertex=0)
    cf_roll = canonical_form(rolled, _graph_distances(rolled, faces), query, n_samples=60, seed_vertex=0)
    # Compare up to a rigid motion (each is expressed in its own scan's frame).
    r, t = kabsch(cf_roll.positions, cf_flat.positions, allow_reflection=True)
    err = np.linalg.norm(cf_roll.positions @ r.T + t - cf_flat.positions, axis=1)
    # Euclidean shapes differ by tens of mm; canonical forms agree to about a mm.
    r0, t0 = kabsch(rolled[query], flat[query], allow_reflection=True)
    euclid = np.linalg.norm(rolled[query] @ r0.T + t0 - flat[query], axis=1)
    assert euclid.mean() > 10.0
    assert err.mean() < 1.0 and err.max() < 3.0, (err.mean(), err.max())
    assert (np.diff(cf_flat.stress_history) <= 1e-9 * cf_flat.stress_history[0]).all()


def test_canonical_form_frame_is_the_scan_frame():
    # With exact geodesics (intrinsic = Euclidean in the unrolled (u, v) plane), the canonical form
    # of the rolled sheet is the flat sheet, and the Procrustes step puts it onto the scan.
    uv, _ = _grid()
    flat = np.column_stack([uv, np.zeros(len(uv))])
    rows = lambda s: np.linalg.norm(uv[None] - uv[s][:, None], axis=-1)  # noqa: E731
    query = np.arange(0, len(uv), 5)
    cf = canonical_form(flat, rows, query, n_samples=40, seed_vertex=3)
    assert cf.rel_stress < 1e-4
    np.testing.assert_allclose(cf.positions, flat[query], atol=1e-3)
    radius = 120.0 / np.pi
    ang = uv[:, 0] / radius
    rolled = np.column_stack([radius * np.sin(ang), uv[:, 1], radius * np.cos(ang)])
    cf = canonical_form(rolled, rows, query, n_samples=40, seed_vertex=3)
    # a flat sheet fitted to the half cylinder: its centre plane, y axis along the cylinder
    dy = np.abs(cf.positions[:, 1] - rolled[query, 1])
    assert dy.mean() < 1.0 and dy.max() < 3.0  # a small tilt: the samples are not symmetric


def test_bad_input():
    with pytest.raises(ValueError, match="square"):
        smacof(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="finite"):
        smacof(np.full((5, 5), np.nan))
    with pytest.raises(ValueError, match=r"\(Q, 4\)"):
        place_out_of_sample(np.zeros((4, 3)), np.zeros((2, 3)))


def test_out_of_sample_with_unreached_samples():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(20, 3)) * 10
    q = rng.normal(size=(30, 3)) * 8
    d_q = np.linalg.norm(q[:, None] - x[None], axis=-1)
    d_q[:, :8] = np.inf  # 8 samples do not reach any query point
    d_q[0, 8:] = np.inf  # the first point is reached by nobody
    y = place_out_of_sample(x, d_q, iters=200)
    assert np.isnan(y[0]).all()
    np.testing.assert_allclose(y[1:], q[1:], atol=1e-2)  # 200 Guttman steps from the nearest sample
