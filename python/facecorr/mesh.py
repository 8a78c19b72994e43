"""The triangle mesh every stage works on, with derived quantities cached.

A :class:`Mesh` holds vertices in **millimetres** (float64, (N, 3)) and triangles (int64, (M, 3)),
plus the factor that took the file's units to millimetres so results can be written back in the
scan's own units. Derived quantities (normals, areas, boundary, components, KD-tree) are computed
once on first use; a Mesh is treated as immutable after construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .errors import MeshError


@dataclass(eq=False)
class Mesh:
    """A validated triangle mesh in millimetres.

    Parameters
    ----------
    vertices : (N, 3) float array, millimetres.
    faces : (M, 3) int array of vertex indices.
    to_mm : float
        Factor the source coordinates were multiplied by to get millimetres (1 for mm, 10 for cm,
        1000 for m). ``vertices / to_mm`` are the coordinates in the source's units.
    units : str
        The source's units: "mm", "cm" or "m".
    source : str or None
        Where the mesh came from (a path), for messages.
    """

    vertices: np.ndarray
    faces: np.ndarray
    to_mm: float = 1.0
    units: str = "mm"
    source: str | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        f = np.ascontiguousarray(self.faces, dtype=np.int64)
        name = self.source or "mesh"
        if v.ndim != 2 or v.shape[1] != 3:
            raise MeshError(f"{name}: vertices must have shape (N, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise MeshError(f"{name}: faces must have shape (M, 3), got {f.shape}")
        if len(v) == 0:
            raise MeshError(f"{name}: the mesh is empty (no vertices)")
        if len(f) == 0:
            raise MeshError(f"{name}: the mesh has no faces (a point cloud is not supported)")
        if not np.isfinite(v).all():
            raise MeshError(f"{name}: {int((~np.isfinite(v)).any(axis=1).sum())} vertices have NaN or infinite coordinates")
        if f.min() < 0 or f.max() >= len(v):
            raise MeshError(f"{name}: face indices out of range [0, {len(v) - 1}]")
        self.vertices, self.faces = v, f

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @cached_property
    def face_normals_unnormalized(self) -> np.ndarray:
        """(M, 3) cross products (b - a) x (c - a): direction = normal, length = 2 x area (mm^2)."""
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return np.cross(b - a, c - a)

    @cached_property
    def face_areas(self) -> np.ndarray:
        """(M,) triangle areas, mm^2."""
        return 0.5 * np.linalg.norm(self.face_normals_unnormalized, axis=1)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(N, 3) unit area-weighted vertex normals (zero for isolated vertices)."""
        n = np.zeros_like(self.vertices)
        fn = self.face_normals_unnormalized
        for k in range(3):
            np.add.at(n, self.faces[:, k], fn)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    @cached_property
    def vertex_areas(self) -> np.ndarray:
        """(N,) barycentric vertex areas (a third of each incident triangle), mm^2."""
        a = np.zeros(self.n_vertices)
        for k in range(3):
            np.add.at(a, self.faces[:, k], self.face_areas / 3.0)
        return a

    @cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) unique undirected edges, sorted pairs (i < j)."""
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        e.sort(axis=1)
        return np.unique(e, axis=0)

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """(B,) sorted ids of vertices on a boundary edge (an edge used by one triangle)."""
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        e.sort(axis=1)
        uniq, counts = np.unique(e, axis=0, return_counts=True)
        return np.unique(uniq[counts == 1].ravel())

    @cached_property
    def is_boundary(self) -> np.ndarray:
        """(N,) bool, True on boundary vertices."""
        mask = np.zeros(self.n_vertices, dtype=bool)
        mask[self.boundary_vertices] = True
        return mask

    @cached_property
    def components(self) -> np.ndarray:
        """(N,) connected-component label of each vertex (0 = the largest by area)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        e = self.edges
        n = self.n_vertices
        g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        _, labels = connected_components(g, directed=False)
        area = np.bincount(labels, weights=self.vertex_areas)
        order = np.argsort(-area, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        return rank[labels]

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal, mm."""
        return float(np.linalg.norm(self.vertices.max(axis=0) - self.vertices.min(axis=0)))

    def to_source_units(self, points_mm: np.ndarray) -> np.ndarray:
        """Convert points (…, 3) in mm back to the source's units."""
        return np.asarray(points_mm, dtype=np.float64) / self.to_mm
