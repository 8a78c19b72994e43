"""MVEE (Khachiyan) against a direct convex optimisation, containment and affine equivariance."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import minimize

from facecorr.landmarks.paper.mvee import DegenerateError, mvee


def _brute_force_log_volume(points: np.ndarray) -> float:
    """Reference: min -log det(L) s.t. ||L x_i + b|| <= 1 (convex in (L, b) for L SPD), solved by
    SLSQP from several starts; returns log of the optimal volume up to the unit-ball constant
    (= -log det L)."""
    n, d = points.shape
    tri = np.tril_indices(d)
    best = np.inf
    rng = np.random.default_rng(0)
    for start in range(4):
        c0 = points.mean(0) + 0.05 * rng.standard_normal(d) * points.std()
        r0 = np.linalg.norm(points - c0, axis=1).max() * (1.2 + 0.2 * start)
        l0 = np.eye(d) / r0
        z0 = np.concatenate([l0[tri], -l0 @ c0])

        def unpack(z):
            l = np.zeros((d, d))
            l[tri] = z[: len(tri[0])]
            return l, z[len(tri[0]):]

        def objective(z):
            l, _ = unpack(z)
            return -np.sum(np.log(np.abs(np.diag(l)) + 1e-300))

        def cons(z):
            l, b = unpack(z)
            return 1.0 - np.sum((points @ l.T + b) ** 2, axis=1)

        res = minimize(objective, z0, constraints=[{"type": "ineq", "fun": cons}], method="SLSQP",
                       options={"maxiter": 2000, "ftol": 1e-13})
        if res.success and cons(res.x).min() > -1e-7:
            best = min(best, res.fun)
    return best


@pytest.mark.parametrize("d,n,seed", [(2, 6, 0), (2, 9, 1), (3, 7, 2), (3, 12, 3)])
def test_matches_convex_reference(d, n, seed):
    pts = np.random.default_rng(seed).normal(size=(n, d)) * np.arange(1, d + 1)
    e = mvee(pts)
    assert e.contains(pts).all()
    ref = _brute_force_log_volume(pts)
    ours = -0.5 * np.log(np.linalg.det(e.A))  # -log det L with A = L^T L
    # tol=1e-7 -> relative volume error ~1e-7; SLSQP is the looser side.
    assert abs(ours - ref) < 1e-4, (ours, ref)


def test_known_answer_square_and_cube():
    # The MVEE of a square's corners is its circumcircle; of a cube's corners the circumsphere.
    sq = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float) * 3 + [5, -2]
    e = mvee(sq, tol=1e-10)
    np.testing.assert_allclose(e.center, [5, -2], atol=1e-6)
    np.testing.assert_allclose(e.A, np.eye(2) / 18, atol=1e-7)
    cube = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    e = mvee(cube, tol=1e-10)
    np.testing.assert_allclose(e.A, np.eye(3) / 3, atol=1e-7)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(5, 40))
def test_contains_all_and_affine_equivariant(seed, n):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3))
    e = mvee(pts)
    assert e.contains(pts).all()
    # Some point lies on the boundary (the ellipsoid is tight).
    assert e.mahalanobis2(pts).max() > 1 - 1e-5
    # MVEE(T x + t) = T MVEE(x) + t: center maps, A -> T^-T A T^-1.
    t = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    shift = rng.normal(size=3) * 10
    e2 = mvee(pts @ t.T + shift)
    np.testing.assert_allclose(e2.center, t @ e.center + shift, atol=1e-4 * (1 + np.abs(shift).max()))
    ti = np.linalg.inv(t)
    np.testing.assert_allclose(e2.A, ti.T @ e.A @ ti, rtol=1e-4, atol=1e-5 * np.abs(e2.A).max())


def test_degenerate_coplanar_raises_or_regularises():
    rng = np.random.default_rng(0)
    xy = rng.normal(size=(20, 2))
    pts = np.column_stack([xy, np.full(20, 4.0)])  # coplanar z = 4
    with pytest.raises(DegenerateError, match="span only 2 of 3"):
        mvee(pts)
    e = mvee(pts, regularization=0.5)
    assert e.contains(pts).all()
    np.testing.assert_allclose(e.semi_axes[0], 0.5, rtol=1e-9)  # the thickness
    # In-plane part equals the 2-D MVEE.
    e2 = mvee(xy)
    np.testing.assert_allclose(e.A[:2, :2], e2.A, rtol=1e-6, atol=1e-9)
    with pytest.raises(DegenerateError):
        mvee(pts[:3])
    one = mvee(pts[:1], regularization=1.0)
    assert one.contains(pts[:1]).all()


def test_bad_input():
    with pytest.raises(ValueError, match="non-empty"):
        mvee(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="NaN"):
        mvee(np.array([[0, 0], [1, np.nan], [0, 1]]))
