"""Nearest-neighbour queries in 3-D: a KD-tree with scipy ``cKDTree`` semantics (Rust, kiddo),
the MHD, closest points on triangles and the distance of points to a mesh's surface.

Queries run in parallel in facecorr's thread pool (2 threads unless ``FACECORR_THREADS`` says
otherwise) with the GIL released.
"""

from __future__ import annotations

import math

import numpy as np

from .. import _core

__all__ = ["KDTree", "closest_point_on_triangles", "mhd", "voxel_subsample"]


def _as_points(a, what: str) -> np.ndarray:
    """(n, 3) C-contiguous float64 copy/view of ``a``; ValueError on a bad shape or NaN."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} must be a numeric array of shape (n, 3): {e}") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what} must have shape (n, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} contains NaN or inf")
    return np.ascontiguousarray(arr)


class KDTree:
    """KD-tree over a fixed set of 3-D points, built once.

    Parameters
    ----------
    points : (N, 3) array_like of float
        The points (mm by convention). float32 and float64 are accepted; queries run in float64.
        N may be 0 (every query then reports missing neighbours).

    Attributes
    ----------
    data : (N, 3) float64 ndarray
        The points.
    n : int
        Number of points.
    """

    def __init__(self, points):
        self.data = _as_points(points, "points")
        self.data.setflags(write=False)
        self.n = int(self.data.shape[0])
        self._tree = _core.KdTree(self.data)

    def query(self, q, k: int = 1, distance_upper_bound: float = math.inf):
        """Nearest neighbours, as ``scipy.spatial.cKDTree.query``.

        Parameters
        ----------
        q : (3,) or (Q, 3) array_like of float
            Query point(s).
        k : int
            Number of neighbours (>= 1).
        distance_upper_bound : float
            Only neighbours with distance strictly below this are returned.

        Returns
        -------
        dist : float64 ndarray, shape () / (Q,) for k == 1, (k,) / (Q, k) otherwise
            Euclidean distances, ascending; ``inf`` for missing neighbours.
        idx : int64 ndarray, same shape
            Point indices; ``n`` for missing neighbours.
        """
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"k must be an integer >= 1, got {k!r}")
        ub = float(distance_upper_bound)
        if math.isnan(ub) or ub < 0:
            raise ValueError(f"distance_upper_bound must be >= 0, got {distance_upper_bound!r}")
        qa = np.asarray(q, dtype=np.float64) if not isinstance(q, np.ndarray) else q
        single = qa.ndim == 1
        qa = _as_points(qa.reshape(1, -1) if single else qa, "query points")
        dist, idx = self._tree.query(qa, int(k), ub)
        if k == 1:
            dist, idx = dist[:, 0], idx[:, 0]
        if single:
            return dist[0], idx[0]
        return dist, idx

    def query_ball_point(self, q, r: float):
        """Indices of all points within distance ``r`` (inclusive), as ``cKDTree.query_ball_point``.

        Parameters
        ----------
        q : (3,) or (Q, 3) array_like of float
            Query point(s).
        r : float
            Radius (>= 0).

        Returns
        -------
        list of int64 ndarray (one per query, sorted ascending), or one ndarray for a (3,) query.
        """
        r = float(r)
        if not math.isfinite(r) or r < 0:
            raise ValueError(f"r must be a finite number >= 0, got {r!r}")
        qa = np.asarray(q, dtype=np.float64) if not isinstance(q, np.ndarray) else q
        single = qa.ndim == 1
        qa = _as_points(qa.reshape(1, -1) if single else qa, "query points")
        out = self._tree.query_ball_point(qa, r)
        return out[0] if single else out

    def query_hinted(self, q, hint):
        """The nearest point of each query, as ``query(q, k=1)`` (the same distances and indices),
        searched within the distance to ``hint`` (Q,) int: a point index per query, e.g. its
        nearest point before the query moved a little (an ICP step); negative or >= n: no hint.
        Off the surface, where an unbounded search backtracks through much of the tree, a good
        hint makes the query several times cheaper.

        Returns dist (Q,) float64, idx (Q,) int64.
        """
        qa = _as_points(np.asarray(q, dtype=np.float64), "query points")
        h = np.asarray(hint)
        if h.shape != (len(qa),) or not np.issubdtype(h.dtype, np.integer):
            raise ValueError(f"hint must be ({len(qa)},) integers, got {h.dtype} {h.shape}")
        return self._tree.query_hinted(qa, np.ascontiguousarray(h, dtype=np.int64))

    def ball_sums(self, q, r: float, values):
        """Per query, the number of tree points within distance ``r`` (inclusive, as
        :meth:`query_ball_point`) and the sums of their rows of ``values``, without listing the
        balls: the product of the ball-membership matrix with ``values``, up to rounding (a tree
        box wholly inside a ball adds its precomputed sum; ~1e-16 relative per addition).

        Parameters
        ----------
        q : (Q, 3) array_like of float; r : float >= 0;
        values : (N, C) array_like of float, one row per tree point.

        Returns
        -------
        count : (Q,) int64; sums : (Q, C) float64.
        """
        r = float(r)
        if not math.isfinite(r) or r < 0:
            raise ValueError(f"r must be a finite number >= 0, got {r!r}")
        qa = _as_points(np.asarray(q, dtype=np.float64), "query points")
        v = np.asarray(values, dtype=np.float64)
        if v.ndim != 2 or len(v) != self.n:
            raise ValueError(f"values must have shape ({self.n}, C), got {v.shape}")
        return self._tree.ball_sums(qa, r, v)

    def __repr__(self) -> str:
        return f"KDTree(n={self.n})"


def mhd(p, f_vertices, tree: "KDTree | None" = None) -> float:
    """Modified Hausdorff distance MHD(P, F) = (1/N_P) sum_i min_j |p_i - f_j| (the paper's MHD).

    Parameters
    ----------
    p : (N_P, 3) points (e.g. registered template vertices), mm.
    f_vertices : (N_F, 3) the scan's vertices, mm.
    tree : optional KDTree over ``f_vertices`` (e.g. ``Mesh.kdtree``), built when None.

    Returns
    -------
    float, mm (one-directional: from P to F, as the paper defines it).
    """
    p = np.asarray(p, dtype=np.float64)
    f = np.asarray(f_vertices, dtype=np.float64)
    for name, a in (("P", p), ("F", f)):
        if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
            raise ValueError(f"mhd: {name} must have shape (n >= 1, 3), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"mhd: {name} has NaN or infinite coordinates")
    d, _ = (tree if tree is not None else KDTree(f)).query(p, k=1)
    return float(np.asarray(d, dtype=np.float64).mean())


def voxel_subsample(points: np.ndarray, ids: np.ndarray, spacing: float) -> np.ndarray:
    """Subset of ``ids`` with at most one vertex per cube of side ``spacing`` (mm): the vertex
    nearest to its cell's centre (equally near: the first in ``ids``), returned sorted. O(n) (cells
    grouped by hashing, ``_core.equal_rows``: on a 56k-vertex scan 22 -> 5 ms for a lexsort, the
    same subset: the reference in ``tests/test_landmarks_parts.py``); keeps the candidate sets evenly spread
    whatever the scan's resolution."""
    from .. import _core

    ids = np.asarray(ids, dtype=np.int64)
    if len(ids) == 0 or spacing <= 0:
        return ids
    p = points[ids]
    cell = np.floor(p / spacing)
    off = np.linalg.norm(p - (cell + 0.5) * spacing, axis=1)
    _, group = _core.equal_rows(np.ascontiguousarray(cell))
    n_groups = int(group.max()) + 1
    best = np.full(n_groups, np.inf)
    np.minimum.at(best, group, off)
    pos = np.flatnonzero(off == best[group])  # the nearest of each cell (ties: all of them)
    first = np.full(n_groups, len(ids))
    np.minimum.at(first, group[pos], pos)  # ties: the first
    return np.sort(ids[first])


def closest_point_on_triangles(p: np.ndarray, tri: np.ndarray):
    """Closest points of triangles ``tri`` (K, 3, 3) to points ``p`` (K, 3), pairwise (mm).

    Returns (distances (K,), closest points (K, 3)); :func:`facecorr.geometry.closest.
    closest_points_on_triangles` (barycentric form, the one implementation) does the work.
    """
    from .closest import closest_points_on_triangles

    tri = np.asarray(tri, dtype=np.float64).reshape(-1, 3, 3)
    bary, dist = closest_points_on_triangles(p, tri[:, 0], tri[:, 1], tri[:, 2])
    return dist, np.einsum("kc,kcd->kd", bary, tri)
