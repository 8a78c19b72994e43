"""Canonical forms (Elad & Kimmel 2003): an isometry-invariant embedding of a surface in R^3.

The paper (§3.1) embeds the face by least-squares MDS of geodesic distances (fast marching) and
defines the edge potentials as relative landmark positions in that embedding. Embedding all N
vertices (N x N distances) is neither needed nor affordable, so:

1. **Samples**: ``n_samples`` vertices by farthest-point sampling (Euclidean, cheap, and on a
   face patch it covers the surface as evenly as geodesic FPS would), always including a seed.
2. **Distances**: one geodesic propagation per sample (``distance_rows`` callback, the Rust FMM
   in production) gives the (S, N) matrix; its (S, S) block is symmetrised.
3. **SMACOF** (de Leeuw's majorisation with the Guttman transform) minimises the raw stress
   ``sum_{i<j} (||x_i - x_j|| - d_ij)^2`` from a classical-MDS (Torgerson) start; each Guttman
   step cannot increase the stress (majorisation), the history is returned and checked by tests.
4. **Out-of-sample placement** of the query vertices (only those we need: landmarks in training,
   candidates in prediction): for each query q, minimise its own stress to the fixed samples
   ``sum_j (||y - x_j|| - d_qj)^2`` by the same Guttman iteration (per point: y <- mean_j
   (x_j + d_qj (y - x_j)/||y - x_j||)), started from the landmark-MDS (Nystrom, de Silva &
   Tenenbaum) triangulation. Why: it optimises the *same* least-squares criterion the samples were
   embedded with, whereas LMDS alone is exact only for Euclidean distances and biases points
   when geodesic distances are not (a face is not flat); LMDS is a good closed-form start.
5. **Frame**: the embedding is defined up to an orthogonal transform; we fix it by an orthogonal
   Procrustes fit (rotation, reflection allowed because MDS' handedness is arbitrary, no scaling)
   of the sample embedding onto the samples' scan coordinates, so canonical coordinates live in
   the scan's frame and relative positions can be compared after a rigid pose normalisation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...geometry.transforms import kabsch


def farthest_point_sample(points: np.ndarray, k: int, start: int = 0) -> np.ndarray:
    """(k,) indices of a Euclidean farthest-point sample of points (n, 3), beginning at ``start``."""
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    if not 0 <= start < n:
        raise ValueError(f"farthest_point_sample: start {start} out of range [0, {n})")
    k = min(int(k), n)
    idx = np.empty(k, dtype=np.int64)
    idx[0] = start
    d = np.linalg.norm(p - p[start], axis=1)
    for i in range(1, k):
        idx[i] = int(np.argmax(d))
        d = np.minimum(d, np.linalg.norm(p - p[idx[i]], axis=1))
    return idx


def stress(x: np.ndarray, d: np.ndarray) -> float:
    """Raw stress sum_{i<j} (||x_i - x_j|| - d_ij)^2 of an embedding x (S, k) for distances d (S, S)."""
    dx = np.linalg.norm(x[:, None] - x[None], axis=-1)
    return 0.5 * float(np.sum((dx - d) ** 2))


def classical_mds(d: np.ndarray, dim: int = 3) -> np.ndarray:
    """Torgerson MDS: (S, dim) coordinates from double-centred squared distances."""
    s = len(d)
    j = np.eye(s) - 1.0 / s
    b = -0.5 * j @ (d**2) @ j
    w, v = np.linalg.eigh(b)
    order = np.argsort(w)[::-1][:dim]
    return v[:, order] * np.sqrt(np.maximum(w[order], 0.0))


def smacof(d: np.ndarray, dim: int = 3, init: np.ndarray | None = None, max_iter: int = 300,
           rel_tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares MDS by SMACOF with unit weights.

    Parameters
    ----------
    d : (S, S) symmetric non-negative dissimilarities (mm), zero diagonal.
    dim : embedding dimension.
    init : (S, dim) start; default classical MDS.
    max_iter, rel_tol : stop when the relative stress decrease of an iteration is below rel_tol.

    Returns
    -------
    x : (S, dim) embedding; history : (iterations + 1,) raw stress after each step (non-increasing).
    """
    d = np.asarray(d, dtype=np.float64)
    if d.ndim != 2 or d.shape[0] != d.shape[1] or len(d) < dim + 1:
        raise ValueError(f"smacof: need a square (S, S) matrix with S > {dim}, got {d.shape}")
    if not np.isfinite(d).all() or (d < 0).any():
        raise ValueError("smacof: dissimilarities must be finite and non-negative")
    s = len(d)
    x = classical_mds(d, dim) if init is None else np.array(init, dtype=np.float64)
    x = x - x.mean(0)
    hist = [stress(x, d)]
    for _ in range(max_iter):
        dx = np.linalg.norm(x[:, None] - x[None], axis=-1)
        ratio = np.divide(d, dx, out=np.zeros_like(d), where=dx > 1e-12)
        b = -ratio
        np.fill_diagonal(b, 0.0)
        np.fill_diagonal(b, -b.sum(axis=1))
        x = b @ x / s  # Guttman transform (unit weights: V^+ = I/S on centred configurations)
        hist.append(stress(x, d))
        if hist[-2] - hist[-1] <= rel_tol * max(hist[-2], 1e-300):
            break
    return x, np.asarray(hist)


def place_out_of_sample(x: np.ndarray, d_q: np.ndarray, iters: int = 30) -> np.ndarray:
    """Positions (Q, k) of new points given their distances d_q (Q, S) to embedded samples x (S, k).

    Start: landmark MDS (Nystrom) triangulation; then per-point Guttman iterations on the point's
    stress to the samples (each step cannot increase it). Infinite distances (samples that do not
    reach the point) are left out of that point's stress; a point reached by fewer than k + 1
    samples gets NaN.
    """
    x = np.asarray(x, dtype=np.float64)
    d_q = np.asarray(d_q, dtype=np.float64)
    s, k = x.shape
    if d_q.ndim != 2 or d_q.shape[1] != s:
        raise ValueError(f"place_out_of_sample: d_q must be (Q, {s}), got {d_q.shape}")
    w = np.isfinite(d_q)
    full = w.all(axis=1)
    dz = np.where(w, d_q, 0.0)
    y = np.empty((len(d_q), k))
    # LMDS: with centred samples Xc, ||y - x_j||^2 - mean_i ||x_j - x_i||^2 = |y|^2 - 2 y.x_j - const,
    # and pinv(Xc) kills constants, so y = -1/2 pinv(Xc) (d_q^2 - mean_d2).
    mu = x.mean(0)
    xc = x - mu
    dx2 = np.linalg.norm(x[:, None] - x[None], axis=-1) ** 2
    mean_d2 = dx2.mean(axis=1)
    pinv = np.linalg.pinv(xc)  # (k, S)
    y[full] = -0.5 * (dz[full] ** 2 - mean_d2[None]) @ pinv.T + mu
    if (~full).any():  # partial rows: start at the nearest reached sample
        near = np.argmin(np.where(w[~full], d_q[~full], np.inf), axis=1)
        y[~full] = x[near]
    cnt = w.sum(axis=1)
    for _ in range(iters):
        diff = y[:, None, :] - x[None]  # (Q, S, k)
        dist = np.linalg.norm(diff, axis=-1)
        ratio = np.divide(dz, dist, out=np.zeros_like(dz), where=dist > 1e-12)
        terms = (x[None] + ratio[..., None] * diff) * w[..., None]
        y = terms.sum(axis=1) / np.maximum(cnt, 1)[:, None]
    y[cnt < k + 1] = np.nan
    return y


@dataclass
class CanonicalForm:
    """A fitted canonical form of a surface region.

    samples (S,) vertex ids; embedding (S, 3) their canonical positions (scan frame, mm);
    rows (S, N) geodesic distances from the samples to every vertex (mm, inf = unreached);
    stress_history (T,) SMACOF raw stress; rel_stress float = sqrt(stress / sum d^2);
    positions (Q, 3) canonical positions of the query vertices given at construction.
    """

    samples: np.ndarray
    embedding: np.ndarray
    rows: np.ndarray
    stress_history: np.ndarray
    rel_stress: float
    positions: np.ndarray | None = None

    def place(self, query: np.ndarray, iters: int = 30) -> np.ndarray:
        """(Q, 3) canonical positions (scan frame, mm) of vertex ids ``query`` (out-of-sample);
        NaN rows for vertices (nearly) unreached from the samples (another component)."""
        query = np.asarray(query, dtype=np.int64)
        return place_out_of_sample(self.embedding, self.rows[:, query].T, iters=iters)


def canonical_form(vertices: np.ndarray, distance_rows: Callable[[np.ndarray], np.ndarray],
                   query: np.ndarray, region: np.ndarray | None = None, n_samples: int = 100,
                   seed_vertex: int | None = None, max_iter: int = 300) -> CanonicalForm:
    """Canonical form of a surface region, with the positions of the query vertices.

    Parameters
    ----------
    vertices : (N, 3) scan vertices, mm.
    distance_rows : callable(sources (S,)) -> (S, N) geodesic distances, mm (inf = unreached).
    query : (Q,) vertex ids to place (more can be placed later with ``CanonicalForm.place``).
    region : (R,) vertex ids the samples are drawn from (default all); e.g. a geodesic disk around
        the nose so hair, neck and shoulders of a raw scan do not dominate the embedding.
    n_samples : number of farthest-point samples S.
    seed_vertex : first sample (default the region's first vertex).
    """
    v = np.asarray(vertices, dtype=np.float64)
    region = np.arange(len(v)) if region is None else np.asarray(region, dtype=np.int64)
    query = np.asarray(query, dtype=np.int64)
    start = 0 if seed_vertex is None else int(np.flatnonzero(region == seed_vertex)[0])
    samples = region[farthest_point_sample(v[region], n_samples, start=start)]
    rows = np.asarray(distance_rows(samples), dtype=np.float64)
    dss = rows[:, samples]
    # Keep the samples connected to the seed's component (a raw scan can have islands).
    ok = np.isfinite(dss[0]) if seed_vertex is not None else np.isfinite(dss).sum(1) > len(dss) // 2
    ok &= np.isfinite(dss[:, ok]).all(axis=1)
    if ok.sum() < 4:
        raise ValueError("canonical_form: fewer than 4 connected samples (disconnected surface?)")
    samples, rows = samples[ok], rows[ok]
    dss = rows[:, samples]
    dss = 0.5 * (dss + dss.T)
    np.fill_diagonal(dss, 0.0)
    x, hist = smacof(dss, 3, max_iter=max_iter)
    r, t = kabsch(x, v[samples], allow_reflection=True)
    cf = CanonicalForm(samples=samples, embedding=x @ r.T + t, rows=rows, stress_history=hist,
                       rel_stress=float(np.sqrt(2 * hist[-1] / np.sum(dss**2))))
    cf.positions = cf.place(query)
    return cf
