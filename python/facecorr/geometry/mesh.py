"""The triangle mesh every stage works on, with derived quantities cached.

A :class:`Mesh` holds vertices in **millimetres** (float64, (N, 3)) and triangles (int64, (M, 3)),
plus the factor that took the file's units to millimetres so results can be written back in the
scan's own units. Derived quantities (normals, areas, boundary, components, KD-tree) are computed
once on first use; a Mesh is treated as immutable after construction.

A scan's colour, when its file has one, travels with the mesh through every step that renumbers
vertices or triangles (:meth:`Mesh.submesh`, :meth:`Mesh.centred_outward`, the loader's
cleaning): per-vertex RGB (``vertex_colors``) or a texture image with per-corner texture
coordinates (``face_uv`` + ``texture``); :mod:`facecorr.geometry.colour` samples it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .. import _core
from ..errors import MeshError


def vertex_normals(vertices, faces) -> np.ndarray:
    """(N, 3) unit area-weighted vertex normals of a triangle mesh (zero for isolated vertices);
    the Rust kernel behind :attr:`Mesh.vertex_normals`, for vertices that change (a fit's rounds)."""
    return _core.mesh_vertex_normals(np.ascontiguousarray(vertices, dtype=np.float64),
                                     np.ascontiguousarray(faces, dtype=np.int64))


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
    meta : dict, counts and notes of the loader.
    vertex_colors : (N, 3) float array in [0, 1], or None
        Per-vertex RGB (stored as float32; uint8 input is divided by 255, an alpha column dropped).
    face_uv : (M, 3, 2) float array, or None
        Texture coordinates of each triangle's three corners (a corner can differ between the
        triangles of one vertex: texture seams); given together with ``texture``.
    texture : (H, W, 3) uint8 image, or None
        The texture image, row 0 at the top (conventions: :mod:`facecorr.geometry.colour`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    to_mm: float = 1.0
    units: str = "mm"
    source: str | None = None
    meta: dict = field(default_factory=dict)
    vertex_colors: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    texture: np.ndarray | None = None

    def __post_init__(self):
        name = self.source or "mesh"
        f = np.asarray(self.faces)
        if f.dtype.kind not in "iu":
            if f.dtype.kind != "f" or not np.all(np.isfinite(f)) or not np.array_equal(f, np.round(f)):
                raise MeshError(f"{name}: face indices must be integers, got {f.dtype} values such as "
                                f"{f.ravel()[:3].tolist()}")
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        f = np.ascontiguousarray(f, dtype=np.int64)
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
        self._check_colour(name)

    def _check_colour(self, name: str) -> None:
        """Validate and normalise the optional colour fields (MeshError on a mismatch)."""
        if self.vertex_colors is not None:
            c = np.asarray(self.vertex_colors)
            if c.ndim != 2 or c.shape[0] != len(self.vertices) or c.shape[1] not in (3, 4):
                raise MeshError(f"{name}: vertex_colors must have shape ({len(self.vertices)}, 3), got {c.shape}")
            c = c[:, :3].astype(np.float32) / (255.0 if c.dtype == np.uint8 else 1.0)
            if not np.isfinite(c).all() or c.min() < 0.0 or c.max() > 1.0:
                raise MeshError(f"{name}: vertex_colors must be finite values in [0, 1] (or uint8)")
            self.vertex_colors = np.ascontiguousarray(c, dtype=np.float32)
        if (self.face_uv is None) != (self.texture is None):
            raise MeshError(f"{name}: face_uv and texture go together (one is missing)")
        if self.face_uv is not None:
            uv = np.ascontiguousarray(self.face_uv, dtype=np.float64)
            if uv.shape != (len(self.faces), 3, 2):
                raise MeshError(f"{name}: face_uv must have shape ({len(self.faces)}, 3, 2), got {uv.shape}")
            if not np.isfinite(uv).all():
                raise MeshError(f"{name}: face_uv has NaN or infinite texture coordinates")
            img = np.asarray(self.texture)
            if img.ndim == 2:
                img = np.repeat(img[:, :, None], 3, axis=2)
            if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8 or 0 in img.shape:
                raise MeshError(f"{name}: texture must be an (H, W, 3) uint8 image, got {img.dtype} {img.shape}")
            self.face_uv, self.texture = uv, np.ascontiguousarray(img[:, :, :3])

    @property
    def color_source(self) -> str | None:
        """"texture" (texture image + coordinates; preferred when a file has both), "vertex"
        (per-vertex RGB) or None (no colour)."""
        if self.face_uv is not None:
            return "texture"
        return "vertex" if self.vertex_colors is not None else None

    def _colour_of(self, vertex_ids=None, face_ids=None, face_corners=None) -> dict:
        """The colour fields of a mesh made of ``vertex_ids`` / ``face_ids`` of this one (corners
        reordered by ``face_corners``), as keyword arguments for :class:`Mesh`."""
        out = {}
        if self.vertex_colors is not None:
            out["vertex_colors"] = self.vertex_colors if vertex_ids is None else self.vertex_colors[vertex_ids]
        if self.face_uv is not None:
            uv = self.face_uv if face_ids is None else self.face_uv[face_ids]
            out["face_uv"] = uv if face_corners is None else uv[:, face_corners]
            out["texture"] = self.texture
        return out

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
        return _core.mesh_face_areas(self.vertices, self.faces)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(N, 3) unit area-weighted vertex normals (zero for isolated vertices)."""
        return vertex_normals(self.vertices, self.faces)

    @cached_property
    def vertex_areas(self) -> np.ndarray:
        """(N,) barycentric vertex areas (a third of each incident triangle), mm^2."""
        return _core.mesh_vertex_areas(self.vertices, self.faces)

    @cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) int64 unique undirected edges, sorted pairs (i < j), lexicographic order."""
        return _core.mesh_edges(self.faces, self.n_vertices)

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """(B,) int64 sorted ids of vertices on a boundary edge (an edge used by one triangle)."""
        return _core.mesh_boundary_vertices(self.faces, self.n_vertices)

    @cached_property
    def outer_boundary(self) -> np.ndarray:
        """(B,) int64 sorted ids of the vertices of the longest boundary curve: a scan's outer
        border (holes, nostrils and eye openings are shorter curves); empty for a closed mesh.
        Boundary edges are the edges used by one triangle; a curve is a connected set of them."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        f = self.faces
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        key, count = np.unique(e[:, 0] * np.int64(self.n_vertices) + e[:, 1], return_counts=True)
        key = key[count == 1]
        if len(key) == 0:
            return np.zeros(0, dtype=np.int64)
        a, b = key // self.n_vertices, key % self.n_vertices
        graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(self.n_vertices, self.n_vertices))
        _, label = connected_components(graph, directed=False)
        length = np.bincount(label[a], weights=np.linalg.norm(self.vertices[a] - self.vertices[b], axis=1))
        longest = int(np.argmax(length))
        return np.unique(np.concatenate([a, b])[np.concatenate([label[a], label[b]]) == longest]).astype(np.int64)

    @cached_property
    def is_boundary(self) -> np.ndarray:
        """(N,) bool, True on boundary vertices."""
        mask = np.zeros(self.n_vertices, dtype=bool)
        mask[self.boundary_vertices] = True
        return mask

    @cached_property
    def components(self) -> np.ndarray:
        """(N,) int64 connected-component label of each vertex: 0 = the largest by area, then by
        decreasing area (equal areas: the component with the lower vertex id first). A vertex in
        no triangle is a component of its own."""
        return _core.mesh_components(self.vertices, self.faces)

    @property
    def n_components(self) -> int:
        """Number of connected components (isolated vertices count)."""
        return int(self.components.max()) + 1

    @cached_property
    def component_areas(self) -> np.ndarray:
        """(C,) area of each connected component (label order of :attr:`components`), mm²."""
        label = self.components[self.faces[:, 0]]
        return np.bincount(label, weights=self.face_areas, minlength=self.n_components)

    @cached_property
    def signed_volume(self) -> float:
        """Σ over triangles of (a · (b × c)) / 6, mm³: the volume enclosed with the origin, positive
        when the triangles are wound so that their normals point away from it."""
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)

    def centred_outward(self) -> tuple["Mesh", np.ndarray]:
        """(mesh, offset): this mesh moved so that the median of its vertices (per coordinate) sits
        on the origin, with its triangles wound so that the normals point outward (away from the
        head), and the (3,) offset (mm) to add back to positions found on it.

        Where a scan sits must not change an answer, and far from the origin float64 loses the
        precision the fits need; the median, unlike the bounding box, ignores a stray spike. Scanners
        and converters often write inward-facing triangles, which would turn every normal test of
        the fits around: a face scan is a cap curved about the head's centre, so seen from a point
        in its middle its outward winding is the one with a positive :attr:`signed_volume` (the
        sides, which curve back, make it so). A mesh already centred and outward is returned itself
        (its caches are kept).
        """
        offset = np.median(self.vertices, axis=0)
        extent = float(np.abs(np.percentile(self.vertices, 99, axis=0) - np.percentile(self.vertices, 1, axis=0)).max())
        if np.abs(offset).max() <= 1e-9 * max(1.0, extent):
            offset = np.zeros(3)
            moved = self
        else:
            moved = Mesh(self.vertices - offset, self.faces, to_mm=self.to_mm, units=self.units, source=self.source,
                         meta=dict(self.meta), **self._colour_of())
        if moved.signed_volume < 0:
            moved = Mesh(moved.vertices, moved.faces[:, [0, 2, 1]], to_mm=self.to_mm, units=self.units,
                         source=self.source, meta={**self.meta, "rewound": True},
                         **self._colour_of(face_corners=[0, 2, 1]))
        return moved, offset

    def submesh(self, vertex_mask: np.ndarray) -> tuple[Mesh, np.ndarray]:
        """The part of the mesh on the selected vertices.

        Parameters
        ----------
        vertex_mask : (N,) bool, or (K,) int vertex ids.

        Returns
        -------
        mesh : Mesh with the selected vertices (in ascending id order) and the triangles whose
            three vertices are all selected; same units/to_mm/source, meta copied, colour kept.
        old_ids : (K,) int64, ``old_ids[i]`` is the id in ``self`` of the new vertex ``i``.

        Raises
        ------
        MeshError
            If the selection keeps no triangle.
        """
        mask = np.asarray(vertex_mask)
        if mask.dtype == bool:
            if mask.shape != (self.n_vertices,):
                raise MeshError(f"vertex_mask must have shape ({self.n_vertices},), got {mask.shape}")
        else:
            ids = mask.astype(np.int64, copy=False).ravel()
            if ids.size and (ids.min() < 0 or ids.max() >= self.n_vertices):
                raise MeshError(f"vertex ids out of range [0, {self.n_vertices - 1}]")
            mask = np.zeros(self.n_vertices, dtype=bool)
            mask[ids] = True
        old_ids = np.flatnonzero(mask).astype(np.int64)
        keep = mask[self.faces].all(axis=1)
        if not keep.any():
            raise MeshError(f"{self.source or 'mesh'}: the selection keeps no triangle")
        new_id = np.full(self.n_vertices, -1, dtype=np.int64)
        new_id[old_ids] = np.arange(len(old_ids))
        sub = Mesh(self.vertices[old_ids], new_id[self.faces[keep]], to_mm=self.to_mm,
                   units=self.units, source=self.source, meta=dict(self.meta),
                   **self._colour_of(vertex_ids=old_ids, face_ids=np.flatnonzero(keep)))
        return sub, old_ids

    def largest_component(self) -> tuple[Mesh, np.ndarray]:
        """The largest connected piece by area (the face, for a scan with debris).

        Returns ``(mesh, old_ids)`` as :meth:`submesh`.
        """
        return self.submesh(self.components == 0)

    @cached_property
    def kdtree(self):
        """:class:`facecorr.spatial.KDTree` over the vertices (built on first use)."""
        from .spatial import KDTree

        return KDTree(self.vertices)

    @cached_property
    def surface(self):
        """``facecorr._core.Surface``: the triangles prepared for closest-point queries in Rust
        (``surface.closest(points (Q, 3), k)`` -> face, bary, point, dist, normal, boundary share),
        with the vertex normals and boundary flags interpolated; built on first use, on the
        :attr:`kdtree`'s tree (one KD-tree of the scan serves both)."""
        return _core.Surface(self.vertices, np.ascontiguousarray(self.faces, dtype=np.int64),
                             np.ascontiguousarray(self.vertex_normals, dtype=np.float64),
                             np.ascontiguousarray(self.is_boundary, dtype=bool), self.kdtree._tree)

    @cached_property
    def triangle_set(self):
        """:class:`facecorr.geometry.closest.TriangleSet` of the triangles (closest-point queries;
        built on first use, with the KD-tree)."""
        from .closest import TriangleSet

        return TriangleSet(self.vertices, self.faces, tree=self.kdtree)

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal, mm."""
        return float(np.linalg.norm(self.vertices.max(axis=0) - self.vertices.min(axis=0)))

    def to_source_units(self, points_mm: np.ndarray) -> np.ndarray:
        """Convert points (…, 3) in mm back to the source's units."""
        return np.asarray(points_mm, dtype=np.float64) / self.to_mm
