"""Plain numpy/scipy references and test meshes for the Rust kernels (KD-tree, geodesics, FP)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

ICT_NPZ = Path(__file__).resolve().parents[1] / "python" / "facecorr" / "data" / "ict" / "ict_face_model.npz"


def grid_mesh(nx: int, ny: int, h: float):
    """Planar (nx+1) x (ny+1) grid in z = 0 with spacing h, squares split by a diagonal."""
    xs, ys = np.meshgrid(np.arange(nx + 1) * h, np.arange(ny + 1) * h)
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    a = (j * (nx + 1) + i).ravel()
    b, c, d = a + 1, a + nx + 2, a + nx + 1
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F.astype(np.int64)


@lru_cache(maxsize=None)
def sphere_mesh(subdivisions: int = 5, radius: float = 50.0):
    """Icosphere (10242 vertices for 5 subdivisions) of the given radius (mm)."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


@lru_cache(maxsize=None)
def ict_face_mesh():
    """The ICT neutral face's narrow-face region: its vertices and the triangles entirely inside
    it (re-indexed, unreferenced vertices dropped). About 9k vertices, mm."""
    z = np.load(ICT_NPZ)
    V = z["neutral"].astype(np.float64)
    F = z["triangles"].astype(np.int64)
    keep = z["narrow_face"]
    F = F[keep[F].all(axis=1)]
    used = np.unique(F)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def edge_graph(V, F) -> sp.csr_matrix:
    """Symmetric sparse matrix of edge lengths of the mesh."""
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    w = np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)
    n = len(V)
    A = sp.coo_matrix((w, (e[:, 0], e[:, 1])), shape=(n, n))
    return (A + A.T).tocsr()


def dijkstra_reference(V, F, sources) -> np.ndarray:
    """Edge-graph shortest paths to the nearest source (scipy.sparse.csgraph)."""
    return dijkstra(edge_graph(V, F), directed=False, indices=np.atleast_1d(sources), min_only=True)


def exact_geodesic_reference(V, F, source: int) -> np.ndarray:
    """Exact polyhedral geodesic distances (pygeodesic, MMP/Chen-Han style exact algorithm)."""
    import pygeodesic.geodesic as pg

    alg = pg.PyGeodesicAlgorithmExact(np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int32))
    d, _ = alg.geodesicDistances(np.array([source], dtype=np.int32), None)
    return np.asarray(d, dtype=np.float64)


def great_circle(V, center: int, radius: float) -> np.ndarray:
    """Great-circle distances on a sphere centred at the origin."""
    u = V / np.linalg.norm(V, axis=1, keepdims=True)
    return radius * np.arccos(np.clip(u @ u[center], -1.0, 1.0))


def clipped_disk_area(V, F, d, r: float) -> float:
    """Area of {x : d(x) <= r} for d linear in each triangle (vertex values d), numpy only.

    Per triangle with sorted corner values d0 <= d1 <= d2 the region is a small triangle at
    corner 0 (r <= d1) or the triangle minus a small triangle at corner 2 (r > d1).
    """
    dv = np.sort(d[F], axis=1)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    d0, d1, d2 = dv[:, 0], dv[:, 1], dv[:, 2]
    frac = np.zeros(len(F))
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = (r > d0) & (r <= d1)
        frac[lo] = (r - d0[lo]) ** 2 / ((d1[lo] - d0[lo]) * (d2[lo] - d0[lo]))
        hi = (r > d1) & (r < d2)
        frac[hi] = 1 - (d2[hi] - r) ** 2 / ((d2[hi] - d0[hi]) * (d2[hi] - d1[hi]))
    frac[r >= d2] = 1.0
    return float((frac * area).sum())


def fingerprint_reference(V, F, distance_rows, radii) -> np.ndarray:
    """FP from given per-centre vertex distances (C, N): clipped disk area / (pi r^2)."""
    out = np.empty((len(distance_rows), len(radii)))
    for i, d in enumerate(distance_rows):
        for j, r in enumerate(radii):
            out[i, j] = clipped_disk_area(V, F, d, r) / (np.pi * r * r)
    return out
