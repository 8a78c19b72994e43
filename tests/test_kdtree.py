"""facecorr.spatial.KDTree vs scipy.spatial.cKDTree (identical results up to distance ties)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial import cKDTree

from facecorr.geometry.spatial import KDTree


def _assert_same_knn(d, i, dr, ir, n):
    """Distances equal to 1e-12; indices equal wherever the distance is not tied."""
    np.testing.assert_allclose(d, dr, rtol=0, atol=1e-12)
    assert ((i == ir) | np.isclose(d, dr, rtol=0, atol=1e-12)).all()
    # where a neighbour is missing both report inf / n
    assert ((ir == n) == (i == n)).all()


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(5000, 3)) * [40, 30, 20]
    Q = rng.normal(size=(1000, 3)) * [40, 30, 20]
    return P, Q


@pytest.mark.parametrize("k", [1, 8])
def test_knn_matches_ckdtree(cloud, k):
    P, Q = cloud
    d, i = KDTree(P).query(Q, k=k)
    dr, ir = cKDTree(P).query(Q, k=k)
    assert d.shape == dr.shape and i.shape == ir.shape and i.dtype == np.int64
    _assert_same_knn(d, i, dr, ir, len(P))
    # ties do not happen on a continuous random cloud: identical indices
    assert (i == ir).all()


@pytest.mark.parametrize("k", [1, 8])
def test_distance_upper_bound(cloud, k):
    P, Q = cloud
    d, i = KDTree(P).query(Q, k=k, distance_upper_bound=6.0)
    dr, ir = cKDTree(P).query(Q, k=k, distance_upper_bound=6.0)
    assert np.isinf(dr).any()  # the bound matters in this test
    _assert_same_knn(d, i, dr, ir, len(P))


def test_query_ball_point(cloud):
    P, Q = cloud
    got = KDTree(P).query_ball_point(Q[:200], 5.0)
    ref = cKDTree(P).query_ball_point(Q[:200], 5.0)
    assert sum(len(r) for r in ref) > 200
    for g, r in zip(got, ref):
        np.testing.assert_array_equal(g, np.sort(r))


def test_ball_sums_are_the_csr_product(cloud):
    """ball_sums == (ball-membership CSR matrix from cKDTree) @ values up to rounding (whole tree
    boxes add their precomputed sums: another order of the same additions), and the counts exactly."""
    from scipy import sparse

    P, Q = cloud
    vals = np.column_stack([P, P[:, 0] * P[:, 1], np.sin(P[:, 2])])
    for r in (0.5, 5.0, 20.0):
        count, sums = KDTree(P).ball_sums(Q[:300], r, vals)
        balls = [np.sort(b) for b in cKDTree(P).query_ball_point(Q[:300], r)]
        n = np.array([len(b) for b in balls])
        member = sparse.csr_matrix((np.ones(int(n.sum())), np.concatenate(balls), np.concatenate([[0], np.cumsum(n)])),
                                   shape=(300, len(P)))
        np.testing.assert_array_equal(count, n)
        assert count.dtype == np.int64 and sums.shape == (300, 5)
        # each sum within 1e-13 of the sum of its terms' magnitudes
        np.testing.assert_array_less(np.abs(sums - member @ vals), 1e-13 * (member @ np.abs(vals)) + 1e-300)


def test_query_hinted_is_the_nearest_point(cloud):
    """Hinted nearest-point queries give cKDTree's answer whatever the hints (good, bad, none)."""
    P, Q = cloud
    far = np.vstack([Q, Q * 7.0 + 30.0])
    dr, ir = cKDTree(P).query(far)
    t = KDTree(P)
    rng = np.random.default_rng(1)
    for hint in (ir, rng.integers(0, len(P), len(far)), np.full(len(far), -1), np.full(len(far), len(P))):
        d, i = t.query_hinted(far, hint)
        np.testing.assert_array_equal(i, ir)
        np.testing.assert_array_equal(d, t.query(far)[0])
        np.testing.assert_allclose(d, dr, rtol=1e-12)
    with pytest.raises(ValueError, match="hint must be"):
        t.query_hinted(far, ir[:-1])


def test_ball_sums_bad_input(cloud):
    P, Q = cloud
    t = KDTree(P)
    with pytest.raises(ValueError, match="values must have shape"):
        t.ball_sums(Q, 1.0, np.ones((len(P) - 1, 2)))
    with pytest.raises(ValueError, match="r must be"):
        t.ball_sums(Q, -1.0, np.ones((len(P), 2)))
    c, s = t.ball_sums(Q[:3], 0.0, np.ones((len(P), 0)))
    assert s.shape == (3, 0) and c.shape == (3,)


def test_single_point_float32_and_attributes(cloud):
    P, Q = cloud
    t = KDTree(P.astype(np.float32))
    assert t.n == len(P) and t.data.dtype == np.float64
    d, i = t.query(Q[0].astype(np.float32))
    dr, ir = cKDTree(P.astype(np.float32).astype(np.float64)).query(Q[0].astype(np.float32).astype(np.float64))
    assert np.ndim(d) == 0 and int(i) == int(ir) and abs(float(d) - dr) < 1e-12
    d8, i8 = t.query(Q[0], k=8)
    assert d8.shape == (8,) and i8.shape == (8,)
    np.testing.assert_array_equal(t.query_ball_point(t.data[0], 0.0), [0])


def test_k_larger_than_n_and_ties():
    P = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0]], float)
    d, i = KDTree(P).query([[0, 0, 0]], k=5)
    dr, ir = cKDTree(P).query([[0, 0, 0]], k=5)
    _assert_same_knn(d, i, dr, ir, 3)
    assert set(i[0, 1:3]) == {1, 2} and (i[0, 3:] == 3).all()


def test_empty_tree():
    t = KDTree(np.zeros((0, 3)))
    d, i = t.query(np.zeros((2, 3)), k=2)
    assert np.isinf(d).all() and (i == 0).all()


@pytest.mark.parametrize(
    "points, q, kw, msg",
    [
        (np.zeros((4, 2)), None, {}, "shape"),
        (np.array([[0, 0, np.nan]]), None, {}, "NaN"),
        (np.zeros((4, 3)), np.zeros((2, 4)), {}, "shape"),
        (np.zeros((4, 3)), np.array([[np.inf, 0, 0]]), {}, "NaN or inf"),
        (np.zeros((4, 3)), np.zeros((2, 3)), {"k": 0}, "k must"),
        (np.zeros((4, 3)), np.zeros((2, 3)), {"distance_upper_bound": -1}, "distance_upper_bound"),
        (np.zeros((4, 3)), np.zeros((2, 3)), {"distance_upper_bound": np.nan}, "distance_upper_bound"),
    ],
)
def test_bad_input(points, q, kw, msg):
    with pytest.raises(ValueError, match=msg) as e:
        KDTree(points).query(q, **kw)
    assert "\n" not in str(e.value)


def test_bad_radius():
    with pytest.raises(ValueError, match="r must"):
        KDTree(np.zeros((3, 3))).query_ball_point(np.zeros(3), -1.0)


coords = st.floats(-100, 100, allow_nan=False, width=64)


@settings(max_examples=40, deadline=None)
@given(
    P=arrays(np.float64, st.tuples(st.integers(1, 300), st.just(3)), elements=coords),
    Q=arrays(np.float64, st.tuples(st.integers(1, 30), st.just(3)), elements=coords),
    k=st.integers(1, 10),
)
def test_property_agrees_with_ckdtree(P, Q, k):
    d, i = KDTree(P).query(Q, k=k)
    dr, ir = cKDTree(P).query(Q, k=k)
    # duplicated points are common here: compare distances, and the indices must point at
    # points at the reported distance
    np.testing.assert_allclose(d, dr, rtol=1e-12, atol=1e-12)
    ii = np.atleast_2d(i.reshape(len(Q), -1))
    dd = np.atleast_2d(d.reshape(len(Q), -1))
    for qi in range(len(Q)):
        ok = ii[qi] < len(P)
        dist = np.linalg.norm(P[ii[qi][ok]] - Q[qi], axis=1)
        np.testing.assert_allclose(dist, dd[qi][ok], rtol=1e-12, atol=1e-12)
        assert len(set(ii[qi][ok])) == ok.sum()


@settings(max_examples=40, deadline=None)
@given(
    P=arrays(np.float64, st.tuples(st.integers(1, 300), st.just(3)), elements=st.floats(-5, 5, allow_nan=False, width=16)),
    Q=arrays(np.float64, st.tuples(st.integers(1, 30), st.just(3)), elements=coords),
    seed=st.integers(0, 2**16),
)
def test_property_hinted_nearest_agrees_with_ckdtree(P, Q, seed):
    """The single-nearest search (facecorr's own tree, rust/src/nearest.rs) from any hint: cKDTree's
    distance, and among tied points (many here: coarse coordinates) the lowest index."""
    t = KDTree(P)
    dr, _ = cKDTree(P).query(Q)
    hints = np.random.default_rng(seed).integers(-1, len(P) + 1, len(Q))
    for d, i in (t.query(Q), t.query_hinted(Q, hints)):
        np.testing.assert_allclose(d, dr, rtol=1e-12, atol=1e-12)
        dist = np.linalg.norm(P - Q[:, None, :], axis=2)  # (Q, P)
        lowest = np.argmax(dist <= dist.min(axis=1, keepdims=True), axis=1)
        np.testing.assert_array_equal(i, lowest)
