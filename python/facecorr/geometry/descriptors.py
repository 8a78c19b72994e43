"""Surface descriptors (Rust): the Finger Print (Sun & Abidi 2001; paper §3.1)."""

from __future__ import annotations

import numpy as np

from .. import _core
from .geodesic import _as_faces, _as_indices, _as_radii
from .spatial import _as_points

__all__ = ["fingerprint"]


def fingerprint(V, F, centers, radii) -> np.ndarray:
    """Finger Print of mesh vertices: area of the geodesic disk of radius r / (pi r^2).

    Distances are fast-marching geodesics from each centre, linearly interpolated inside the
    triangles; the disk area is exact for that field (the part of each triangle where the
    interpolated distance is <= r). Centres run in parallel, each a propagation truncated just
    beyond ``max(radii)``. For many calls on one mesh use
    :meth:`facecorr.geodesic.GeodesicSolver.fingerprint`.

    Parameters
    ----------
    V : (N, 3) array_like of float
        Vertices (mm).
    F : (M, 3) array_like of int
        Triangles.
    centers : (C,) array_like of int
        Centre vertex indices.
    radii : (R,) array_like of float
        Radii (mm), > 0.

    Returns
    -------
    (C, R) float64 ndarray
        1 on a plane; on a sphere of radius Rs, 2 Rs^2 (1 - cos(r / Rs)) / r^2.
    """
    Va = _as_points(V, "vertices")
    if Va.shape[0] == 0:
        raise ValueError("the mesh has no vertices")
    Fa = _as_faces(F, Va.shape[0])
    c = _as_indices(centers, Va.shape[0], "center")
    r = _as_radii(radii)
    return _core.fingerprint(Va, Fa, c, r)
