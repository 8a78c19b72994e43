"""Geodesic distances on triangle meshes (Rust): fast marching and Dijkstra.

:class:`GeodesicSolver` precomputes, once per mesh, the edge graph, the vertex -> face
adjacency and the fast-marching update stencils (including the unfolded virtual triangles that
split obtuse angles), then answers many queries. Queries with ``max_distance`` stop the
propagation there, so their cost is proportional to the area reached.

Fast marching (``method="fmm"``) follows Kimmel & Sethian (1998): vertices are accepted in order
of distance; a vertex is updated from each triangle whose two other corners are accepted. The
update first assumes a point source (the virtual source is unfolded from the two corner values,
as Novotni & Klein 2002; exact on planar and developable patches whenever the straight ray
crosses the triangle) and otherwise a plane wave; an update is used only if its characteristic
comes from inside the triangle and it is causal, else the edge updates are. Obtuse angles are
split by unfolding neighbouring triangles until a vertex makes two acute virtual triangles.
``method="dijkstra"`` is the shortest path along edges (an upper bound of the geodesic).

Units are the mesh's (millimetres in facecorr).
"""

from __future__ import annotations

import math

import numpy as np

from .. import _core
from .spatial import _as_points

__all__ = ["GeodesicSolver", "distances"]

_METHODS = ("fmm", "dijkstra")


def _as_faces(F, n: int) -> np.ndarray:
    try:
        arr = np.asarray(F)
    except (TypeError, ValueError) as e:
        raise ValueError(f"faces must be an integer array of shape (m, 3): {e}") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"faces must have shape (m, 3), got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError("the mesh has no faces")
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind == "f" and np.isfinite(arr).all() and (arr == np.round(arr)).all():
            arr = arr.astype(np.int64)
        else:
            raise ValueError(f"faces must hold integer vertex indices, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.int64)
    lo, hi = int(arr.min()), int(arr.max())
    if lo < 0 or hi >= n:
        raise ValueError(f"face vertex index {lo if lo < 0 else hi} out of range [0, {n})")
    return arr


def _as_indices(a, n: int, what: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(a))
    if arr.ndim != 1:
        raise ValueError(f"{what} must be an integer or a 1-D array of integers, got shape {arr.shape}")
    if arr.dtype.kind not in "iu":
        if arr.size == 0:
            arr = arr.astype(np.int64)
        else:
            raise ValueError(f"{what} must hold integer vertex indices, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= n):
        bad = int(arr.min()) if arr.min() < 0 else int(arr.max())
        raise ValueError(f"{what} index {bad} out of range [0, {n})")
    return arr


def _check_method(method: str) -> str:
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    return method


def _check_max_distance(max_distance):
    if max_distance is None:
        return None
    m = float(max_distance)
    if math.isnan(m) or m < 0:
        raise ValueError(f"max_distance must be >= 0 or None, got {max_distance!r}")
    return m


class GeodesicSolver:
    """Geodesic distance queries on one triangle mesh, precomputed once.

    Parameters
    ----------
    V : (N, 3) array_like of float
        Vertex positions (mm). Must be finite.
    F : (M, 3) array_like of int
        Triangles, indices in [0, N). Faces with a repeated index are ignored.
    """

    def __init__(self, V, F):
        self.vertices = _as_points(V, "vertices")
        if self.vertices.shape[0] == 0:
            raise ValueError("the mesh has no vertices")
        self.faces = _as_faces(F, self.vertices.shape[0])
        self.n_vertices = int(self.vertices.shape[0])
        self._solver = _core.GeodesicSolver(self.vertices, self.faces)

    @property
    def n_obtuse_split(self) -> int:
        """Number of obtuse angles split by unfolding for the fast-marching updates."""
        return self._solver.n_obtuse_split

    def distances(self, sources, max_distance=None, method: str = "fmm") -> np.ndarray:
        """Geodesic distance from every vertex to the nearest source.

        Parameters
        ----------
        sources : int or (S,) array_like of int
            Source vertex indices (S >= 1).
        max_distance : float, optional
            Stop the propagation there (mm): vertices farther away get ``inf``.
        method : {"fmm", "dijkstra"}

        Returns
        -------
        (N,) float64 ndarray
            Distances (mm); ``inf`` where unreached (other components, beyond max_distance).
        """
        _check_method(method)
        md = _check_max_distance(max_distance)
        src = _as_indices(sources, self.n_vertices, "source")
        if src.size == 0:
            raise ValueError("sources is empty")
        return self._solver.distances(src, md, method)

    def distance_matrix(self, sources, max_distance=None, method: str = "fmm") -> np.ndarray:
        """One propagation per source (in parallel).

        Parameters
        ----------
        sources : (S,) array_like of int
            Source vertex indices.
        max_distance : float, optional
            Truncation distance (mm); farther entries are ``inf``.
        method : {"fmm", "dijkstra"}

        Returns
        -------
        (S, N) float64 ndarray
            Row ``i`` holds the distances from ``sources[i]`` (mm).
        """
        _check_method(method)
        md = _check_max_distance(max_distance)
        src = _as_indices(sources, self.n_vertices, "source")
        return self._solver.distance_matrix(src, md, method)

    def fingerprint(self, centers, radii) -> np.ndarray:
        """Finger Print descriptor: geodesic disk area / (pi r^2) for each centre and radius.

        The disk is ``{x : d(x) <= r}`` with the fast-marching distance from the centre linearly
        interpolated in each triangle; its area is exact for that field (sub-triangle clipping).
        Each centre is one propagation truncated just beyond ``max(radii)``.

        Parameters
        ----------
        centers : (C,) array_like of int
            Centre vertex indices.
        radii : (R,) array_like of float
            Disk radii (mm), > 0.

        Returns
        -------
        (C, R) float64 ndarray
            1 on a plane, < 1 on a sphere (2R^2(1 - cos(r/R))/r^2), > 1 on saddles; disks cut by
            the mesh boundary are smaller.
        """
        c = _as_indices(centers, self.n_vertices, "center")
        r = _as_radii(radii)
        return self._solver.fingerprint(c, r)

    def __repr__(self) -> str:
        return f"GeodesicSolver(n_vertices={self.n_vertices}, n_faces={self.faces.shape[0]})"


def _as_radii(radii) -> np.ndarray:
    try:
        r = np.atleast_1d(np.asarray(radii, dtype=np.float64))
    except (TypeError, ValueError) as e:
        raise ValueError(f"radii must be numbers: {e}") from None
    if r.ndim != 1 or r.size == 0:
        raise ValueError(f"radii must be a non-empty 1-D array, got shape {r.shape}")
    if not (np.isfinite(r).all() and (r > 0).all()):
        raise ValueError("radii must be finite and > 0")
    return np.ascontiguousarray(r)


def distances(V, F, sources, max_distance=None, method: str = "fmm") -> np.ndarray:
    """Geodesic distances (N,) from the nearest of ``sources``; see :meth:`GeodesicSolver.distances`.

    Builds a :class:`GeodesicSolver` for one query; keep a solver for repeated queries.
    """
    _check_method(method)
    _check_max_distance(max_distance)
    return GeodesicSolver(V, F).distances(sources, max_distance=max_distance, method=method)
