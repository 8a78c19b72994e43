"""Per-scan feature machinery shared by training and prediction.

A :class:`ScanFeatures` wraps one mesh with the compiled geodesic solver and KD-tree built once,
caches FP descriptors per vertex (the nose search, the candidate sets and the node potentials ask
for overlapping vertices), and computes canonical-form positions of requested vertices.
"""

from __future__ import annotations

import numpy as np

from .mds import canonical_form


class ScanFeatures:
    """Geodesics, FP descriptors and canonical forms on one mesh (mm).

    Parameters
    ----------
    mesh : facecorr.Mesh (mm); its cached KD-tree and normals are shared, not rebuilt.
    radii : (S,) FP radii, mm.
    """

    def __init__(self, mesh, radii: np.ndarray):
        from ...geometry.geodesic import GeodesicSolver

        self.vertices = mesh.vertices
        self.faces = mesh.faces
        self.tree = mesh.kdtree
        self.normals = mesh.vertex_normals
        self.radii = np.asarray(radii, dtype=np.float64)
        self.solver = GeodesicSolver(self.vertices, self.faces)
        self._fp = {}
        self._cf = {}

    def fingerprint(self, ids) -> np.ndarray:
        """(len(ids), S) FP descriptors at vertex ids (cached)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        missing = np.unique([i for i in ids.tolist() if i not in self._fp])
        if len(missing):
            rows = np.asarray(self.solver.fingerprint(missing, self.radii), dtype=np.float64)
            for i, r in zip(missing.tolist(), rows):
                self._fp[i] = r
        if len(ids) == 0:
            return np.zeros((0, len(self.radii)))
        return np.array([self._fp[i] for i in ids.tolist()])

    def tip_normal(self, vertex: int, radius: float = 8.0) -> np.ndarray:
        """Unit area-weighted mean normal of the faces within ``radius`` mm of a vertex."""
        if not hasattr(self, "_fn"):
            f = self.faces
            a, b, c = (self.vertices[f[:, k]] for k in range(3))
            self._fn = np.cross(b - a, c - a)  # length = 2 x area
            self._fc = (a + b + c) / 3.0
        near = np.linalg.norm(self._fc - self.vertices[vertex], axis=1) < radius
        n = self._fn[near].sum(axis=0)
        return n / max(np.linalg.norm(n), 1e-12)

    def geodesic_disk(self, center: int, radius: float) -> np.ndarray:
        """Sorted vertex ids within geodesic distance ``radius`` (mm) of ``center``."""
        d = np.asarray(self.solver.distances(np.array([center], dtype=np.int64), max_distance=radius))
        return np.flatnonzero(d <= radius)

    def canonical_form(self, query, center: int, region_radius: float, n_samples: int):
        """Canonical form (:class:`.mds.CanonicalForm`) with ``.positions`` (Q, 3) of the query
        vertex ids, scan frame, mm; ``.place(ids)`` places more vertices later.

        Samples are drawn from the geodesic disk of ``region_radius`` around ``center`` (the nose
        tip), so hair, neck and shoulders of a raw scan do not enter the embedding.
        """
        key = (int(center), float(region_radius), int(n_samples))
        if key in self._cf:
            cf = self._cf[key]
            cf.positions = cf.place(query)
            return cf
        region = self.geodesic_disk(center, region_radius)
        if len(region) < 10:
            raise ValueError("canonical form: the region around the nose has fewer than 10 vertices")

        def rows(sources):
            # Everything needed lies in the disk, so distances never exceed its diameter.
            return self.solver.distance_matrix(np.asarray(sources, dtype=np.int64),
                                               max_distance=2.0 * region_radius)

        cf = canonical_form(self.vertices, rows, np.asarray(query, dtype=np.int64), region=region,
                            n_samples=n_samples, seed_vertex=int(center))
        self._cf[key] = cf
        return cf
