"""Closest points on a triangle mesh, with the triangle and barycentric coordinates of each.

:func:`closest_points_on_triangles` is the pairwise kernel (Ericson, *Real-Time Collision
Detection* §5.1.5: the Voronoi region of the point decides vertex, edge or face), vectorised over
pairs and written on the dot products ``ab·ap``, ``ac·ap`` and three per-triangle constants, so
a mesh's triangles are prepared once (:class:`TriangleSet`). :meth:`TriangleSet.closest` finds,
for many query points, the nearest point of the mesh among the triangles around the ``k``
nearest vertices (KD-tree + vertex -> triangle adjacency). Used by the colour transfer
(:mod:`facecorr.geometry.colour`): a registered vertex takes the colour of the scan at its
closest point.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TriangleSet", "closest_points", "closest_points_on_triangles", "vertex_face_adjacency"]


def vertex_face_adjacency(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangles around each vertex, in CSR form.

    Parameters
    ----------
    faces : (M, 3) int vertex ids.
    n_vertices : int, N.

    Returns
    -------
    starts : (N + 1,) int64; the triangles of vertex ``v`` are ``face_ids[starts[v]:starts[v + 1]]``.
    face_ids : (3M,) int64 triangle ids, ascending within each vertex.
    """
    flat = np.asarray(faces, dtype=np.int64).ravel()
    order = np.argsort(flat, kind="stable")
    starts = np.searchsorted(flat[order], np.arange(n_vertices + 1)).astype(np.int64)
    return starts, (order // 3).astype(np.int64)


def _dot(a, b):
    return np.einsum("kd,kd->k", a, b)


def _region_weights(d1, d2, aa, abac, cc):
    """(v, w): barycentric weights of corners b and c of the closest point of each triangle
    (a, b, c) to its point p, from ``d1 = ab·ap``, ``d2 = ac·ap`` and the triangle's ``aa = ab·ab``,
    ``abac = ab·ac``, ``cc = ac·ac`` (Ericson's tests; NaN where a degenerate triangle defeats them)."""
    d3, d4 = d1 - aa, d2 - abac  # ab·bp, ac·bp
    d5, d6 = d1 - abac, d2 - cc  # ab·cp, ac·cp
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = va + vb + vc
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        regions = [  # Ericson's order: the first test that holds decides
            (d1 <= 0) & (d2 <= 0),  # vertex a
            (d3 >= 0) & (d4 <= d3),  # vertex b
            (vc <= 0) & (d1 >= 0) & (d3 <= 0),  # edge ab
            (d6 >= 0) & (d5 <= d6),  # vertex c
            (vb <= 0) & (d2 >= 0) & (d6 <= 0),  # edge ac
            (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),  # edge bc
        ]
        inside = s > 0
        v = np.select(regions, [0.0, 1.0, t_ab, 0.0, 0.0, 1.0 - t_bc], np.where(inside, vb / s, np.nan))
        w = np.select(regions, [0.0, 0.0, 0.0, 1.0, t_ac, t_bc], np.where(inside, vc / s, np.nan))
    return v, w


def _closest_on_edges(p, a, b, c) -> np.ndarray:
    """(K, 3) barycentric coordinates of the nearest point of the three edges of (a, b, c) to p."""
    best = np.full(len(p), np.inf)
    out = np.zeros((len(p), 3))
    for i, j, u, v in ((0, 1, a, b), (1, 2, b, c), (0, 2, a, c)):
        e = v - u
        ee = _dot(e, e)
        t = np.where(ee > 0, np.clip(_dot(p - u, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0), 0.0)
        d = np.linalg.norm(p - (u + t[:, None] * e), axis=1)
        better = d < best
        best = np.where(better, d, best)
        row = np.zeros((len(p), 3))
        row[:, i], row[:, j] = 1.0 - t, t
        out[better] = row[better]
    return out


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Closest point of triangle (a, b, c) to point p, pairwise over K pairs.

    Parameters
    ----------
    p, a, b, c : (K, 3) float arrays (any length unit).

    Returns
    -------
    bary : (K, 3) float64 barycentric coordinates (w.r.t. a, b, c; >= 0, summing to 1) of the
        closest point ``q = bary[:, 0] a + bary[:, 1] b + bary[:, 2] c``.
    dist : (K,) float64, |p - q|.

    A degenerate triangle (zero area) gives the closest point of its three edges.
    """
    p, a, b, c = (np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in (p, a, b, c))
    ab, ac, ap = b - a, c - a, p - a
    v, w = _region_weights(_dot(ab, ap), _dot(ac, ap), _dot(ab, ab), _dot(ab, ac), _dot(ac, ac))
    bary = np.stack([1.0 - v - w, v, w], axis=1)
    bad = ~np.isfinite(bary).all(axis=1)
    if bad.any():
        bary[bad] = _closest_on_edges(p[bad], a[bad], b[bad], c[bad])
    q = bary[:, 0:1] * a + bary[:, 1:2] * b + bary[:, 2:3] * c
    return bary, np.linalg.norm(p - q, axis=1)


class TriangleSet:
    """A mesh's triangles prepared for closest-point queries (built once, queried many times).

    Parameters
    ----------
    vertices : (N, 3) float, mm; faces : (M, 3) int.
    tree : optional :class:`facecorr.spatial.KDTree` over ``vertices`` (e.g. ``Mesh.kdtree``).
    adjacency : optional ``vertex_face_adjacency(faces, N)``.
    """

    def __init__(self, vertices, faces, tree=None, adjacency=None):
        from .spatial import KDTree

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self.tree = tree if tree is not None else KDTree(self.vertices)
        self.adjacency = adjacency if adjacency is not None else vertex_face_adjacency(self.faces, len(self.vertices))
        a = self.vertices[self.faces[:, 0]]
        self._a = a
        self._ab = self.vertices[self.faces[:, 1]] - a
        self._ac = self.vertices[self.faces[:, 2]] - a
        self._aa = _dot(self._ab, self._ab)
        self._abac = _dot(self._ab, self._ac)
        self._cc = _dot(self._ac, self._ac)

    def closest(self, queries: np.ndarray, k: int = 6):
        """Closest point of the mesh to each query, among the triangles around its ``k`` nearest
        vertices.

        That is the true closest point whenever the triangle holding it has a corner among those
        vertices: in practice always for a query on or near a reasonably even mesh (a registered
        template vertex within a few mm of a scan); a query far from the mesh may get a slightly
        farther point of a nearby triangle.

        Returns
        -------
        face : (Q,) int64 triangle of the closest point, -1 if none of the k vertices is in a triangle.
        bary : (Q, 3) float64 barycentric coordinates in ``faces[face]`` order (NaN where face is -1).
        dist : (Q,) float64 distance to it, mm (inf where face is -1).
        """
        q = np.asarray(queries, dtype=np.float64).reshape(-1, 3)
        nq, m = len(q), len(self.faces)
        face = np.full(nq, -1, dtype=np.int64)
        bary = np.full((nq, 3), np.nan)
        dist = np.full(nq, np.inf)
        if nq == 0 or m == 0:
            return face, bary, dist
        starts, face_ids = self.adjacency
        kk = int(min(max(1, k), len(self.vertices)))
        _, nbr = self.tree.query(q, k=kk)
        nbr = np.asarray(nbr, dtype=np.int64).reshape(-1)
        # every (query, triangle around one of its k vertices) pair, each pair once
        lo, cnt = starts[nbr], starts[nbr + 1] - starts[nbr]
        if cnt.sum() == 0:
            return face, bary, dist
        qid = np.repeat(np.repeat(np.arange(nq), kk), cnt)
        pos = np.repeat(lo - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))
        key = np.sort(qid * m + face_ids[pos])  # (a sort and a diff: much quicker than np.unique)
        key = key[np.concatenate([[True], key[1:] != key[:-1]])]
        qid, fid = key // m, key % m
        ap = q[qid] - self._a[fid]
        d1, d2 = _dot(self._ab[fid], ap), _dot(self._ac[fid], ap)
        aa, abac, cc = self._aa[fid], self._abac[fid], self._cc[fid]
        v, w = _region_weights(d1, d2, aa, abac, cc)
        # |v ab + w ac - ap|², from the dot products (the winner's distance is recomputed below)
        d_sq = v * v * aa + 2.0 * v * w * abac + w * w * cc - 2.0 * v * d1 - 2.0 * w * d2 + _dot(ap, ap)
        bad = ~(np.isfinite(v) & np.isfinite(w))
        if bad.any():  # degenerate triangles: the nearest point of their edges
            a = self._a[fid[bad]]
            b3 = _closest_on_edges(q[qid[bad]], a, a + self._ab[fid[bad]], a + self._ac[fid[bad]])
            v[bad], w[bad] = b3[:, 1], b3[:, 2]
            e = v[bad, None] * self._ab[fid[bad]] + w[bad, None] * self._ac[fid[bad]] - ap[bad]
            d_sq[bad] = _dot(e, e)
        # the nearest pair per query (ties: the lowest triangle id, as pairs are sorted by it)
        start = np.flatnonzero(np.concatenate([[True], qid[1:] != qid[:-1]]))
        d_min = np.minimum.reduceat(d_sq, start)
        at_min = np.flatnonzero(d_sq == np.repeat(d_min, np.diff(np.append(start, len(d_sq)))))
        best = at_min[np.concatenate([[True], qid[at_min][1:] != qid[at_min][:-1]])]
        rows, f = qid[best], fid[best]
        vb, wb = v[best], w[best]
        face[rows] = f
        bary[rows] = np.stack([1.0 - vb - wb, vb, wb], axis=1)
        closest = self._a[f] + vb[:, None] * self._ab[f] + wb[:, None] * self._ac[f]
        dist[rows] = np.linalg.norm(q[rows] - closest, axis=1)
        return face, bary, dist


def closest_points(vertices: np.ndarray, faces: np.ndarray, queries: np.ndarray, *, k: int = 6, tree=None,
                   adjacency=None):
    """Closest point of a triangle mesh to each query point: :meth:`TriangleSet.closest` on a
    set built for this call (build one and reuse it for repeated queries, as ``Mesh.triangle_set``)."""
    return TriangleSet(vertices, faces, tree=tree, adjacency=adjacency).closest(queries, k=k)


def smoothstep(lo, hi, x):
    """0 below ``lo``, 1 above ``hi``, 3t² − 2t³ between (C¹); a step at ``hi`` when lo == hi.
    Broadcasts; the same function as the Rust core's ``surface::smoothstep``."""
    lo, hi, x = np.broadcast_arrays(np.asarray(lo, float), np.asarray(hi, float), np.asarray(x, float))
    span = hi - lo
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.where(span > 0, (x - lo) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)
    return np.where(span > 0, t * t * (3.0 - 2.0 * t), (x >= hi).astype(float))


def match_weights(cos_angle, dist, boundary, max_angle_deg, angle_band_deg, max_distance, distance_band,
                  reject_boundary=True) -> np.ndarray:
    """Continuous weight in [0, 1] of each match (the Rust core's ``surface::match_weight``).

    1 well inside the three tests, 0 outside, a smooth ramp across each band: the normal angle
    (``cos_angle`` against ``max_angle_deg`` ± ``angle_band_deg``; may be per match), the
    distance (mm, from ``max_distance − distance_band`` to ``max_distance``) and, if
    ``reject_boundary``, the interpolated boundary share b ∈ [0, 1] (× (1 − b)). Bands of 0 give
    the hard tests. Why ramps: a hard test flips a match on or off for an arbitrarily small move,
    and the fits using it then jump (issue 13, #15).
    """
    a = np.asarray(max_angle_deg, dtype=np.float64)
    hi = np.cos(np.radians(np.maximum(a - angle_band_deg, 0.0)))
    lo = np.cos(np.radians(np.minimum(a + angle_band_deg, 180.0)))
    w = smoothstep(lo, hi, cos_angle)
    if np.isfinite(max_distance):
        w = w * (1.0 - smoothstep(max_distance - distance_band, max_distance, dist))
    if reject_boundary:
        b = np.asarray(boundary, dtype=np.float64)
        # (a share within rounding of 1, e.g. a point on a boundary edge, counts as 1)
        w = w * np.where(b >= 1.0 - 1e-12, 0.0, np.clip(1.0 - b, 0.0, 1.0))
    return w
