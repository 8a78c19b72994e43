"""Protrusion nose-tip candidates: reference check, analytic cases, pose invariance."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facecorr.landmarks.protrusion import ball_protrusion, nose_tip_candidates, smallest_eigenvector


def _grid(n=61, half=60.0, bump=20.0, sigma2=150.0):
    """Height field z = bump * exp(-(x^2+y^2)/sigma2) on a (n x n) grid: points, normals (up)."""
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    z = bump * np.exp(-(x**2 + y**2) / sigma2) + 6 * np.exp(-((x - 35) ** 2 + (y + 30) ** 2) / 60)
    p = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    gx = -2 * x / sigma2 * bump * np.exp(-(x**2 + y**2) / sigma2)
    gy = -2 * y / sigma2 * bump * np.exp(-(x**2 + y**2) / sigma2)
    n_ = np.column_stack([-gx.ravel(), -gy.ravel(), np.ones(x.size)])
    return p, n_ / np.linalg.norm(n_, axis=1, keepdims=True)


def test_matches_numpy_reference():
    p, n = _grid(n=31)
    h, pn, cnt = ball_protrusion(p, n, 19.7)  # not a multiple of the 4 mm grid: no ties at the radius
    rng = np.random.default_rng(0)
    for i in rng.choice(len(p), 25, replace=False):
        q = p[np.linalg.norm(p - p[i], axis=1) <= 19.7]
        c = q.mean(axis=0)
        w, v = np.linalg.eigh(np.cov(q.T, bias=True))
        nn = v[:, 0] if v[:, 0] @ n[i] >= 0 else -v[:, 0]
        assert cnt[i] == len(q)
        np.testing.assert_allclose(pn[i], nn, atol=1e-6)
        assert h[i] == pytest.approx((p[i] - c) @ nn, abs=1e-6)


def test_plane_has_no_protrusion():
    x, y = np.meshgrid(np.linspace(0, 50, 26), np.linspace(0, 50, 26))
    p = np.column_stack([x.ravel(), y.ravel(), 0.3 * x.ravel() - 0.2 * y.ravel()])
    n = np.tile(np.array([-0.3, 0.2, 1.0]) / np.linalg.norm([-0.3, 0.2, 1.0]), (len(p), 1))
    h, pn, _ = ball_protrusion(p, n, 12.0)
    np.testing.assert_allclose(h, 0.0, atol=1e-8)
    np.testing.assert_allclose(pn, n, atol=1e-8)


def test_best_candidate_is_the_apex_and_second_is_the_small_bump():
    p, n = _grid()
    c = nose_tip_candidates(p, n, k=2, radius=25.0, spacing=0.0, min_separation=20.0)
    assert np.linalg.norm(p[c[0][0]] - [0, 0, 20]) < 3.0
    assert c[0][1] > c[1][1] > 0
    assert np.linalg.norm(p[c[1][0]][:2] - [35, -30]) < 6.0
    assert abs(c[0][2] @ [0, 0, 1]) > 0.99


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_invariant_to_pose(seed):
    p, n = _grid(n=41)
    r = Rotation.random(random_state=seed).as_matrix()
    t = np.random.default_rng(seed).normal(0, 100, 3)
    h0, _, _ = ball_protrusion(p, n, 25.0)
    h1, pn1, _ = ball_protrusion(p @ r.T + t, n @ r.T, 25.0)
    np.testing.assert_allclose(h1, h0, atol=1e-6)
    c0 = nose_tip_candidates(p, n, k=1, spacing=0.0)[0]
    c1 = nose_tip_candidates(p @ r.T + t, n @ r.T, k=1, spacing=0.0)[0]
    assert c0[0] == c1[0]
    # the viewing-axis candidate too (on a dome, where it is not the ball's tip)
    p, n = _dome(n=41)
    d0, d1 = (nose_tip_candidates(q, m, k=1, spacing=0.0, extreme_axis=True) for q, m in ((p, n), (p @ r.T + t, n @ r.T)))
    assert len(d0) == 2 and [c[0] for c in d1] == [c[0] for c in d0]


def _ball_protrusion_sparse(points, normals, radius):
    """The previous implementation (scipy CSR product with the ball-membership matrix), kept as the
    reference of the Rust ball sums. Counts must be the same; heights and normals agree up to
    rounding only (the Rust sums add whole KD-tree boxes' precomputed sums, in another order)."""
    from scipy import sparse
    from scipy.spatial import cKDTree

    balls = [np.sort(b) for b in cKDTree(points).query_ball_point(points, radius)]
    count = np.array([len(b) for b in balls])
    member = sparse.csr_matrix((np.ones(int(count.sum())), np.concatenate(balls),
                                np.concatenate([[0], np.cumsum(count)])), shape=(len(points), len(points)))
    x, y, z = (points - points.mean(axis=0)).T
    sums = member @ np.stack([x, y, z, x * x, x * y, x * z, y * y, y * z, z * z], axis=1)
    centroid = sums[:, :3] / count[:, None]
    second = sums[:, 3:] / count[:, None]
    cov = np.empty((len(points), 3, 3))
    for (a, b), col in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)), range(6)):
        cov[:, a, b] = cov[:, b, a] = second[:, col] - centroid[:, a] * centroid[:, b]
    _, vec = np.linalg.eigh(cov)
    pn = vec[:, :, 0]
    pn *= np.where(np.einsum("ij,ij->i", pn, normals) < 0, -1.0, 1.0)[:, None]
    return np.einsum("ij,ij->i", (points - points.mean(axis=0)) - centroid, pn), pn, count


def test_same_as_the_sparse_product_on_a_noisy_surface():
    p, n = _grid(n=45)
    p = p + np.random.default_rng(3).normal(0, 0.3, p.shape)
    h, pn, cnt = ball_protrusion(p, n, 21.3)
    h0, pn0, cnt0 = _ball_protrusion_sparse(p, n, 21.3)
    np.testing.assert_array_equal(cnt, cnt0)
    # heights are mm on a 21 mm ball: 1e-9 mm is rounding, far below any candidate spacing
    np.testing.assert_allclose(h, h0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(pn, pn0, rtol=0, atol=1e-9)


def test_median_height_ignores_a_lone_spike():
    """A single point lifted 14 mm (a hair spike) is the highest protrusion; with the median of
    its 9 nearest points it is not, and the bump's apex leads again (numpy median reference)."""
    p, n = _grid()
    spike = np.argmin(np.linalg.norm(p[:, :2] - [-40, 40], axis=1))
    p = p.copy()
    p[spike, 2] += 14.0
    raw = nose_tip_candidates(p, n, k=1, spacing=0.0)[0]
    assert raw[0] == spike
    best = nose_tip_candidates(p, n, k=1, spacing=0.0, median_k=9)[0]
    assert np.linalg.norm(p[best[0]] - [0, 0, 20]) < 3.0
    h, _, _ = ball_protrusion(p, n, 25.0)
    nb = np.argsort(np.linalg.norm(p[:, None] - p[best[0]], axis=2)[:, 0])[:9]
    assert best[1] == pytest.approx(float(np.median(h[nb])), abs=1e-9)


def test_keep_leaves_floating_pieces_out():
    """Points not kept (a glasses frame floating 12 mm in front of the face) neither become
    candidates nor tilt the balls' planes: the result is that of the face alone."""
    p, n = _grid()
    x, y = np.meshgrid(np.linspace(-30, 30, 31), np.linspace(22, 30, 5))
    bar = np.column_stack([x.ravel(), y.ravel(), 20 * np.exp(-(x.ravel() ** 2 + y.ravel() ** 2) / 150) + 12.0])
    pts = np.vstack([p, bar])
    nrm = np.vstack([n, np.tile([0.0, 0.0, 1.0], (len(bar), 1))])
    keep = np.arange(len(pts)) < len(p)
    with_bar = nose_tip_candidates(pts, nrm, k=2, spacing=0.0)
    alone = nose_tip_candidates(p, n, k=2, spacing=0.0)
    # the frame changes the answer (it moves the apex's plane and so the best point)
    assert [c[0] for c in with_bar] != [c[0] for c in alone]
    kept = nose_tip_candidates(pts, nrm, k=2, spacing=0.0, keep=keep)
    assert [c[0] for c in kept] == [c[0] for c in alone]
    np.testing.assert_allclose([c[1] for c in kept], [c[1] for c in alone], atol=1e-9)


def _dome(n=61, half=60.0, radius=120.0):
    """A broad sphere cap (apex at the origin, looking along +z) with a small sharp bump off the
    apex: the bump protrudes most from its 25 mm ball, the apex is furthest out along the cap's
    axis of least variance (a nose the ball measure misses). Returns points, unit normals."""
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    x, y = x.ravel(), y.ravel()
    bump = 6 * np.exp(-((x - 35) ** 2 + (y + 30) ** 2) / 60)
    z = np.sqrt(radius**2 - x**2 - y**2) - radius + bump
    gb = -2 / 60 * bump
    gx = -x / (z + radius - bump) + gb * (x - 35)
    gy = -y / (z + radius - bump) + gb * (y + 30)
    nrm = np.column_stack([-gx, -gy, np.ones_like(x)])
    return np.column_stack([x, y, z]), nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def test_axis_candidate_finds_the_point_furthest_out():
    p, n = _dome()
    plain = nose_tip_candidates(p, n, k=1, spacing=0.0)
    both = nose_tip_candidates(p, n, k=1, spacing=0.0, extreme_axis=True)
    assert len(plain) == 1 and np.linalg.norm(p[plain[0][0]][:2] - [35, -30]) < 6.0  # the ball: the bump
    assert len(both) == 2 and both[0][0] == plain[0][0]
    assert np.linalg.norm(p[both[1][0]] - [0, 0, 0]) < 3.0  # the axis: the apex
    # the mirror image (outward = -z): still the apex
    flipped = nose_tip_candidates(p * [1, 1, -1], n * [1, 1, -1], k=1, spacing=0.0, extreme_axis=True)
    assert len(flipped) == 2 and np.linalg.norm(p[flipped[1][0]] - [0, 0, 0]) < 3.0
    # the normals decide which way is out: seen from inside, the furthest point is on the rim
    inward = nose_tip_candidates(p, -n, k=1, spacing=0.0, extreme_axis=True)
    assert np.linalg.norm(p[inward[-1][0]][:2]) > 40.0


def test_axis_candidate_is_not_repeated():
    p, n = _grid()
    plain = nose_tip_candidates(p, n, k=2, spacing=0.0, min_separation=20.0)
    both = nose_tip_candidates(p, n, k=2, spacing=0.0, min_separation=20.0, extreme_axis=True)
    assert [c[0] for c in both] == [c[0] for c in plain]  # the apex is already the first


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(1e-3, 1e3), st.floats(0.0, 1.0), st.floats(1e-4, 0.9))
def test_smallest_eigenvector_is_eighs(seed, top, middle_share, smallest_share):
    """The closed-form smallest eigenvector against ``np.linalg.eigh`` on symmetric matrices of any
    orientation and scale, the two larger eigenvalues equal or not (a ball's disk of points):
    the same axis to 1e-9 whenever the smallest eigenvalue is below the middle one by ≥ 1e-3 of
    the largest; a rank-one matrix gives a unit vector across its line, a zero one (1, 0, 0)."""
    rng = np.random.default_rng(seed)
    rot = Rotation.random(4, random_state=seed).as_matrix()
    mid = top * max(middle_share, smallest_share + 1e-3)
    lams = np.array([[top, top, top * smallest_share], [top, mid, top * smallest_share],
                     [top, mid, 0.0], [top, top * (1 - 1e-9), top * smallest_share]])
    cov = np.einsum("nij,nj,nkj->nik", rot, lams, rot)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1)) + rng.normal(0, 1e-14 * top, (4, 1, 1)) * np.eye(3)
    got = smallest_eigenvector(cov)
    ref = np.linalg.eigh(cov)[1][:, :, 0]
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", got, ref)), 1.0, atol=1e-9)
    u = rot[0][:, 0]
    line, zero = smallest_eigenvector(np.stack([np.outer(u, u) * top, np.zeros((3, 3))]))
    assert abs(np.linalg.norm(line) - 1.0) < 1e-12 and abs(line @ u) < 1e-6
    np.testing.assert_array_equal(zero, [1.0, 0.0, 0.0])
