"""Surface roughness: how far each vertex stands off the surface its neighbours describe.

A beard, stubble or hair scanned by a range scanner is a noisy layer: every vertex jumps by
~0.5-1 mm along the normal independently of its neighbours, where skin only shows the sensor's
noise (0.1-0.3 mm). The normal component of the umbrella Laplacian, ``|(v − mean of v's
neighbours) · n|``, measures that jump; averaged over a few millimetres it tells a rough patch
from smooth skin whatever the mesh's resolution (the noise does not shrink with the edge length,
the curvature's share does).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def vertex_adjacency(n_vertices: int, edges: np.ndarray) -> sp.csr_matrix:
    """(N, N) symmetric 0/1 adjacency (CSR) of the undirected ``edges`` (E, 2)."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    a = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    a.data[:] = 1.0  # an edge listed twice counts once
    return a


def smooth_over(adjacency: sp.csr_matrix, values: np.ndarray, n_iter: int) -> np.ndarray:
    """``values`` (N,) averaged ``n_iter`` times over each vertex and its neighbours (a diffusion
    that reaches ~``sqrt(n_iter)`` edges)."""
    s = adjacency + sp.eye(adjacency.shape[0], format="csr")
    deg = np.asarray(s.sum(axis=1)).ravel()
    out = np.asarray(values, dtype=np.float64)
    for _ in range(int(n_iter)):
        out = (s @ out) / deg
    return out


def diffusion_steps(mean_edge_mm: float, radius_mm: float, max_steps: int = 80) -> int:
    """Averaging steps that reach ~``radius_mm`` on a mesh of mean edge ``mean_edge_mm``."""
    return int(np.clip(np.ceil((float(radius_mm) / max(float(mean_edge_mm), 1e-6)) ** 2), 1, max_steps))


def surface_roughness(vertices: np.ndarray, edges: np.ndarray, normals: np.ndarray, radius: float = 2.5,
                      adjacency: sp.csr_matrix | None = None) -> np.ndarray:
    """Per-vertex roughness, mm: ``|(v − mean of its neighbours) · n_v|``, averaged over ~``radius`` mm.

    Parameters
    ----------
    vertices : (N, 3) mm.
    edges : (E, 2) the mesh's undirected edges.
    normals : (N, 3) unit vertex normals.
    radius : mm over which the per-vertex values are averaged (by repeated neighbour averaging).
    adjacency : optional precomputed :func:`vertex_adjacency`.

    Returns
    -------
    (N,) float64, mm. Isolated vertices get 0.
    """
    v = np.asarray(vertices, dtype=np.float64)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    a = adjacency if adjacency is not None else vertex_adjacency(len(v), e)
    deg = np.asarray(a.sum(axis=1)).ravel()
    mean_nb = (a @ v) / np.maximum(deg, 1.0)[:, None]
    r = np.abs(np.einsum("ij,ij->i", v - mean_nb, np.asarray(normals, dtype=np.float64)))
    r[deg == 0] = 0.0
    mean_edge = float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean()) if len(e) else 1.0
    return smooth_over(a, r, diffusion_steps(mean_edge, radius))
