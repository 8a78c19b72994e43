"""Principal curvatures, principal directions and umbilics of triangle meshes (Rust kernels).

Curvature is estimated per vertex by **local quadric fitting**: the vertices of a neighbourhood
(``rings`` edge rings, default 2, or every vertex within ``radius`` mm reached through edges) are
written in a tangent frame of the area-weighted vertex normal and
``z = a x² + b xy + c y² + d x + e y + f`` is fitted by least squares; the shape operator of that
graph at the vertex gives ``k1 >= k2`` and their directions. Positive curvature bends away from the
normal (a sphere with outward normals has ``k1 = k2 = 1/R``).

Fitting was chosen over Rusinkiewicz's per-face tensor averaging by accuracy on noisy ~1 mm
meshes (``benches/curvature_accuracy.py``, BENCHMARKS.md "Mesh kernels"): with 0.05 mm noise the
median error on a sphere R = 27 mm is 0.0196 1/mm (Rusinkiewicz), 0.0158 (2-ring fit) and 0.0065
(3 mm radius fit); it is better at equal support and its support is an explicit knob. Use
``radius=3`` (mm) on dense noisy scans; the default 2 rings suits ~2-3 mm meshes (ICT model).

Umbilics (the paper's sample points, Salazar et al. §3.2) are where ``k1 ≈ k2``. The rule:

1. smooth ``k1`` and ``k2`` by ``smooth_iters`` passes of 1-ring averaging (equal weights);
2. umbilicity ``u = (k1 - k2) / (|k1| + |k2| + eps)`` in [0, 1], with
   ``eps = eps_rel * median(|k1| + |k2|)`` so that near-flat noisy regions are not umbilic;
3. a vertex is an umbilic when ``u < threshold`` and ``u`` is a strict minimum over its
   ``ring``-ring (ties: lower vertex id), and it is more than ``boundary_rings`` rings from the
   boundary (fits there are one-sided; 0 = only boundary vertices themselves are excluded).

Defaults (``smooth_iters=0, ring=2, threshold=0.5, eps_rel=0.1, boundary_rings=0``) were chosen on
the ICT neutral face (part "face", 9409 vertices, ~2.8 mm edges) by a small grid over
smoothing {0, 1, 2}, ring {1, 2}, threshold {0.2, 0.35, 0.5}, boundary_rings {0, 1, 2}: they give
~140 umbilics with 6 of the 8 method landmarks within 5 mm of one (140 random vertices: 4.35; both
subalare are ~10 mm away for every setting tried); smoothing removes the umbilics at the eye
corners on that coarse mesh. On noisy synthetic scans (~1.2 mm) the umbilics are many (~5 % of the
vertices) and no closer to the landmarks than as many random vertices; ``smooth_iters=1..2`` or a
larger ``radius`` makes them fewer but does not make them better (``benches/umbilic_coverage.py``,
BENCHMARKS.md). On a smooth ellipsoid the rule finds exactly its 4 umbilics.
"""

from __future__ import annotations

import numpy as np

from .. import _core
from ..errors import MeshError

__all__ = ["principal_curvatures", "umbilicity", "umbilics"]


def _vf(V, F):
    try:
        V = np.ascontiguousarray(V, dtype=np.float64)
        F = np.ascontiguousarray(F, dtype=np.int64)
    except (TypeError, ValueError) as e:
        raise MeshError(f"vertices/faces are not numeric arrays: {e}") from None
    if V.ndim != 2 or V.shape[1] != 3:
        raise MeshError(f"vertices must have shape (N, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"faces must have shape (M, 3), got {F.shape}")
    return V, F


def _call(fn, *args, **kw):
    try:
        return fn(*args, **kw)
    except ValueError as e:  # binding validation: one line, re-raised as the package's type
        raise MeshError(str(e)) from None


def principal_curvatures(V, F, rings: int = 2, radius: float | None = None):
    """Principal curvatures and directions at every vertex.

    Parameters
    ----------
    V : (N, 3) float array, millimetres.
    F : (M, 3) int array of vertex indices.
    rings : int
        Neighbourhood size in edge rings (1..20); used when ``radius`` is None. At least 10 points
        are used (more rings are added where there are fewer, e.g. on the boundary).
    radius : float or None
        Neighbourhood radius in mm (vertices within this Euclidean distance, connected to the
        vertex through edges); makes the estimate independent of the mesh resolution.

    Returns
    -------
    k1, k2 : (N,) float64, 1/mm, ``k1 >= k2``; NaN at vertices in no triangle.
    d1, d2 : (N, 3) float64 unit principal directions of k1 and k2, orthogonal to the vertex
        normal, ``d2 = n x d1`` (zero where the curvature is NaN).
    """
    V, F = _vf(V, F)
    r = 0.0 if radius is None else float(radius)
    return _call(_core.principal_curvatures, V, F, int(rings), r)


def umbilicity(V, F, k1=None, k2=None, smooth_iters: int = 0, eps_rel: float = 0.1,
               rings: int = 2, radius: float | None = None) -> np.ndarray:
    """(N,) umbilicity in [0, 1] (0 = umbilic) after smoothing; see the module docstring.

    ``k1``/``k2`` are computed with ``principal_curvatures(V, F, rings, radius)`` when not given.
    """
    V, F = _vf(V, F)
    if k1 is None or k2 is None:
        k1, k2, _, _ = principal_curvatures(V, F, rings=rings, radius=radius)
    k1 = np.ascontiguousarray(k1, dtype=np.float64)
    k2 = np.ascontiguousarray(k2, dtype=np.float64)
    return _call(_core.umbilicity, V, F, k1, k2, int(smooth_iters), float(eps_rel))


def umbilics(V, F, k1=None, k2=None, *, smooth_iters: int = 0, ring: int = 2,
             threshold: float = 0.5, eps_rel: float = 0.1, boundary_rings: int = 0,
             rings: int = 2, radius: float | None = None) -> np.ndarray:
    """Vertex ids of the umbilics (points where ``k1 ≈ k2``), ascending.

    Parameters
    ----------
    V : (N, 3) float array, millimetres.  F : (M, 3) int array.
    k1, k2 : (N,) optional precomputed principal curvatures (1/mm).
    smooth_iters : 1-ring averaging passes applied to k1 and k2 first.
    ring : the umbilicity must be a strict minimum over this many rings.
    threshold : umbilicity must be below this (in (0, 1]).
    eps_rel : ``eps = eps_rel * median(|k1| + |k2|)`` regularises the umbilicity.
    boundary_rings : vertices this close (in rings) to the boundary are never umbilics.
    rings, radius : neighbourhood for :func:`principal_curvatures` when k1/k2 are not given.

    Returns
    -------
    (U,) int64 vertex ids.
    """
    V, F = _vf(V, F)
    if k1 is None or k2 is None:
        k1, k2, _, _ = principal_curvatures(V, F, rings=rings, radius=radius)
    k1 = np.ascontiguousarray(k1, dtype=np.float64)
    k2 = np.ascontiguousarray(k2, dtype=np.float64)
    return _call(_core.umbilics, V, F, k1, k2, int(smooth_iters), int(ring), float(threshold),
                 float(eps_rel), int(boundary_rings))
