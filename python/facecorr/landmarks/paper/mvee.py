"""Minimum-volume enclosing ellipsoid (MVEE) by Khachiyan's algorithm.

The paper (§3.4) turns each class's M-cluster in PCA space into a decision rule
``(p - c)^T A (p - c) <= 1``: the minimum-volume ellipsoid enclosing the cluster.

Algorithm
---------
Khachiyan's barycentric coordinate ascent on the dual (D-optimal design) problem, with the
Todd–Yildirim "away" steps (Wolfe–Atwood) that make it converge fast when few points are on the
boundary. Points ``x_i`` (d-dim) are lifted to ``q_i = (x_i, 1)``; weights ``u`` on the simplex
are updated until ``max_i q_i^T (Q diag(u) Q^T)^{-1} q_i <= (1 + tol) (d + 1)``.

Tolerance
---------
At termination the lifted ellipsoid is a ``(1 + tol)``-approximation; its volume is within a
factor ``(1 + tol)^{(d+1)/2}`` of the optimum (Todd & Yildirim 2007). Because the ellipsoid
recovered from ``u`` may leave points very slightly outside, we finally scale ``A`` by
``1 / max_i (x_i - c)^T A (x_i - c)`` when that maximum exceeds 1, so **every input point is
contained** (a point on the boundary evaluates to 1 up to round-off). The default ``tol = 1e-7``
gives volumes within about 2e-7 (relative) of the optimum.

Degenerate input
----------------
If the points do not span d dimensions (e.g. coplanar points in 3-D, fewer than d + 1 points),
no ellipsoid of positive volume encloses them minimally (the optimum has zero volume). With
``regularization=None`` this raises :class:`DegenerateError` (a ValueError) naming the rank.
With ``regularization=eps`` (mm or whatever the points' unit is) the MVEE is computed in the
points' affine hull and extended by a semi-axis ``eps`` along each missing direction, i.e. the
ellipsoid is a thin slab of half-thickness ``eps`` around the flat one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class DegenerateError(ValueError):
    """The points do not span the space, so the MVEE has zero volume."""


@dataclass(frozen=True)
class Ellipsoid:
    """The set ``{x : (x - center)^T A (x - center) <= 1}``.

    Attributes
    ----------
    center : (d,) float
    A : (d, d) symmetric positive definite float
    """

    center: np.ndarray
    A: np.ndarray

    @property
    def dim(self) -> int:
        return len(self.center)

    def mahalanobis2(self, x: np.ndarray) -> np.ndarray:
        """(n,) values ``(x - c)^T A (x - c)`` for points x (n, d); <= 1 means inside."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        y = x - self.center
        return np.einsum("ni,ij,nj->n", y, self.A, y)

    def contains(self, x: np.ndarray, slack: float = 1e-9) -> np.ndarray:
        """(n,) bool: the points lie inside (with a relative slack for round-off)."""
        return self.mahalanobis2(x) <= 1.0 + slack

    @property
    def volume(self) -> float:
        """Volume: unit-ball volume times ``det(A)^{-1/2}``."""
        from math import gamma, pi

        d = self.dim
        unit = pi ** (d / 2) / gamma(d / 2 + 1)
        return float(unit / np.sqrt(np.linalg.det(self.A)))

    @property
    def semi_axes(self) -> np.ndarray:
        """(d,) semi-axis lengths, ascending."""
        return 1.0 / np.sqrt(np.linalg.eigvalsh(self.A)[::-1])


def _khachiyan(points: np.ndarray, tol: float, max_iter: int) -> tuple[np.ndarray, int]:
    """Weights u (n,) of the D-optimal design of the lifted points; returns (u, iterations)."""
    n, d = points.shape
    q = np.hstack([points, np.ones((n, 1))])  # (n, d+1)
    u = np.full(n, 1.0 / n)
    dp1 = d + 1
    for it in range(max_iter):
        x = (q * u[:, None]).T @ q  # (d+1, d+1)
        # g_i = q_i^T X^{-1} q_i via a Cholesky solve (X is SPD while the points span R^d)
        chol = np.linalg.cholesky(x)
        z = np.linalg.solve(chol, q.T)
        g = np.einsum("ij,ij->j", z, z)
        j_up = int(np.argmax(g))
        g_up = g[j_up]
        if g_up <= (1.0 + tol) * dp1:
            return u, it
        # Away step candidate: the supported point with the smallest g.
        support = u > 0
        j_dn = int(np.flatnonzero(support)[np.argmin(g[support])])
        g_dn = g[j_dn]
        if g_up - dp1 >= dp1 - g_dn:
            step = (g_up - dp1) / (dp1 * (g_up - 1.0))
            u *= 1.0 - step
            u[j_up] += step
        else:
            # Decrease the weight of j_dn, never below zero.
            step = min((dp1 - g_dn) / (dp1 * (g_dn - 1.0)), u[j_dn] / (1.0 - u[j_dn]))
            u *= 1.0 + step
            u[j_dn] -= step
            u[j_dn] = max(u[j_dn], 0.0)
    raise RuntimeError(f"MVEE: Khachiyan's algorithm did not reach tol={tol} in {max_iter} iterations")


def mvee(points: np.ndarray, tol: float = 1e-7, max_iter: int = 100_000,
         regularization: float | None = None) -> Ellipsoid:
    """Minimum-volume ellipsoid enclosing every point.

    Parameters
    ----------
    points : (n, d) float array, n >= 1, finite.
    tol : float
        Relative optimality tolerance of Khachiyan's algorithm (see the module docstring).
    max_iter : int
        Iteration cap (RuntimeError when reached; never hit for sane input).
    regularization : float or None
        None: degenerate input (rank < d) raises :class:`DegenerateError`. A positive value: the
        MVEE in the affine hull, thickened by this semi-axis along the missing directions.

    Returns
    -------
    Ellipsoid with ``(x - center)^T A (x - center) <= 1`` for every input point.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or len(p) == 0:
        raise ValueError(f"mvee: points must be a non-empty (n, d) array, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("mvee: points contain NaN or infinite values")
    if regularization is not None and not (regularization > 0):
        raise ValueError(f"mvee: regularization must be positive, got {regularization}")
    n, d = p.shape
    mean = p.mean(axis=0)
    centered = p - mean
    scale = float(np.abs(centered).max()) if n > 1 else 0.0
    # Rank of the affine hull, relative to the points' extent.
    if scale > 0:
        _, s, vt = np.linalg.svd(centered / scale, full_matrices=True)
        rank = int((s > 1e-9 * max(1.0, s[0])).sum())
    else:
        vt, rank = np.eye(d), 0
    if rank < d:
        if regularization is None:
            raise DegenerateError(
                f"mvee: the {n} points span only {rank} of {d} dimensions (coplanar/collinear or too few); "
                "pass regularization=eps to thicken the ellipsoid")
        basis = vt[:rank].T  # (d, rank) orthonormal basis of the affine hull
        if rank > 0:
            sub = mvee(centered @ basis, tol=tol, max_iter=max_iter)
            center = mean + basis @ sub.center
            a_sub = sub.A
        else:
            center, a_sub = mean, np.zeros((0, 0))
        null = vt[rank:].T  # (d, d - rank)
        a = basis @ a_sub @ basis.T + null @ null.T / regularization**2
        return Ellipsoid(center=center, A=0.5 * (a + a.T))
    # Work on centred, scaled coordinates for conditioning.
    x = centered / scale
    u, _ = _khachiyan(x, tol, max_iter)
    c = u @ x
    cov = (x * u[:, None]).T @ x - np.outer(c, c)
    a = np.linalg.inv(cov) / d
    # Guarantee containment (see module docstring).
    y = x - c
    worst = float(np.einsum("ni,ij,nj->n", y, a, y).max())
    if worst > 1.0:
        a = a / worst
    a = a / scale**2
    return Ellipsoid(center=mean + c * scale, A=0.5 * (a + a.T))
