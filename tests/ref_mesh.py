"""Plain numpy/scipy reference implementations of facecorr's Rust mesh and curvature kernels,
and the analytic test shapes (sphere, cylinder, ellipsoid). Used only by the tests."""

from __future__ import annotations

from collections import deque

import numpy as np
import trimesh

# ----------------------------------------------------------------------------- mesh utilities


def face_normals_unnormalized(V, F):
    a, b, c = (V[F[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


def face_areas(V, F):
    return 0.5 * np.linalg.norm(face_normals_unnormalized(V, F), axis=1)


def vertex_normals(V, F):
    n = np.zeros_like(V, dtype=np.float64)
    fn = face_normals_unnormalized(V, F)
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def vertex_areas(V, F):
    a = np.zeros(len(V))
    fa = face_areas(V, F)
    for k in range(3):
        np.add.at(a, F[:, k], fa / 3.0)
    return a


def _all_edges(F):
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    e.sort(axis=1)
    return e


def edges(F):
    return np.unique(_all_edges(F), axis=0)


def boundary_vertices(F):
    uniq, counts = np.unique(_all_edges(F), axis=0, return_counts=True)
    return np.unique(uniq[counts == 1].ravel())


def components(V, F):
    """Labels with 0 = largest by area (ties: lower vertex id first)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = edges(F)
    n = len(V)
    g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    area = np.bincount(labels, weights=vertex_areas(V, F))
    order = np.argsort(-area, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[labels]


# ----------------------------------------------------------------------------- curvature

MIN_POINTS = 10
MAX_EXTRA_RINGS = 4


def adjacency(n, F):
    nbr = [set() for _ in range(n)]
    for a, b in edges(F):
        nbr[a].add(b)
        nbr[b].add(a)
    return [sorted(s) for s in nbr]


def rings(adj, i, r):
    seen = {i}
    frontier = [i]
    for _ in range(r):
        nxt = []
        for u in frontier:
            for w in adj[u]:
                if w not in seen:
                    seen.add(w)
                    nxt.append(w)
        frontier = nxt
    return sorted(seen)


def neighbourhood(V, adj, i, n_rings, radius):
    if radius > 0:
        seen = {i}
        q = deque([i])
        while q:
            u = q.popleft()
            for w in adj[u]:
                if w not in seen and np.sum((V[w] - V[i]) ** 2) <= radius * radius:
                    seen.add(w)
                    q.append(w)
        if len(seen) >= MIN_POINTS:
            return sorted(seen)
    r = max(n_rings, 1)
    while True:
        nb = rings(adj, i, r)
        if len(nb) >= MIN_POINTS or r >= max(n_rings, 1) + MAX_EXTRA_RINGS:
            return nb
        r += 1


def any_orthogonal(n):
    a = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    c = np.cross(n, a)
    return c / np.linalg.norm(c)


def fit_vertex(p, n, pts):
    """Quadric fit z = a x^2 + b xy + c y^2 + d x + e y + f in the frame (u, n x u, n); the
    shape operator of the graph at the origin, sign such that a sphere with outward normals is
    positive. Returns (k1, k2, d1, d2)."""
    u = any_orthogonal(n)
    w = np.cross(n, u)
    d = pts - p
    x, y, z = d @ u, d @ w, d @ n
    A = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
    a, b, c, fx, fy, _ = np.linalg.lstsq(A, z, rcond=None)[0]
    I = np.array([[1 + fx * fx, fx * fy], [fx * fy, 1 + fy * fy]])
    W = np.sqrt(1 + fx * fx + fy * fy)
    II = -np.array([[2 * a, b], [b, 2 * c]]) / W
    S = np.linalg.solve(I, II)  # shape operator in parameter coordinates
    evals, evecs = np.linalg.eig(S)
    evals = evals.real
    order = np.argsort(-evals)
    k1, k2 = evals[order]
    al, be = evecs[:, order[0]].real
    t = al * u + be * w
    d1 = t / np.linalg.norm(t)
    return k1, k2, d1, np.cross(n, d1)


def principal_curvatures(V, F, n_rings=2, radius=0.0):
    V = np.asarray(V, float)
    N = vertex_normals(V, F)
    adj = adjacency(len(V), F)
    k1 = np.full(len(V), np.nan)
    k2 = np.full(len(V), np.nan)
    d1 = np.zeros((len(V), 3))
    d2 = np.zeros((len(V), 3))
    for i in range(len(V)):
        if not adj[i]:
            continue
        nb = neighbourhood(V, adj, i, n_rings, radius)
        k1[i], k2[i], d1[i], d2[i] = fit_vertex(V[i], N[i], V[nb])
    return k1, k2, d1, d2


def umbilicity(F, k1, k2, smooth_iters=0, eps_rel=0.1):
    adj = adjacency(len(k1), F)
    a, b = np.array(k1, float), np.array(k2, float)
    for _ in range(smooth_iters):
        a = np.array([np.nanmean(a[[i] + adj[i]]) for i in range(len(a))])
        b = np.array([np.nanmean(b[[i] + adj[i]]) for i in range(len(b))])
    eps = eps_rel * np.nanmedian(np.abs(a) + np.abs(b))
    return np.abs(a - b) / (np.abs(a) + np.abs(b) + eps)


def umbilics(F, k1, k2, smooth_iters=0, ring=2, threshold=0.5, eps_rel=0.1, boundary_rings=0):
    n = len(k1)
    adj = adjacency(n, F)
    u = umbilicity(F, k1, k2, smooth_iters, eps_rel)
    near = np.zeros(n, bool)
    for bnd in boundary_vertices(F):
        near[rings(adj, bnd, boundary_rings)] = True
    out = []
    for i in range(n):
        if near[i] or not u[i] < threshold or not adj[i]:
            continue
        nb = [j for j in rings(adj, i, ring) if j != i and np.isfinite(u[j])]
        if all(u[i] < u[j] or (u[i] == u[j] and i < j) for j in nb):
            out.append(i)
    return np.array(out, dtype=np.int64)


# ----------------------------------------------------------------------------- analytic shapes


def sphere(radius=10.0, subdivisions=4):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def cylinder(radius=10.0, length=40.0, n_around=64, n_along=40):
    """Open tube along z (outward normals), a regular grid split into triangles."""
    t = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    z = np.linspace(-length / 2, length / 2, n_along)
    T, Z = np.meshgrid(t, z)
    V = np.stack([radius * np.cos(T), radius * np.sin(T), Z], axis=-1).reshape(-1, 3)
    F = []
    for j in range(n_along - 1):
        for i in range(n_around):
            a = j * n_around + i
            b = j * n_around + (i + 1) % n_around
            c, d = a + n_around, b + n_around
            F += [[a, b, d], [a, d, c]]
    return V, np.array(F, np.int64)


def ellipsoid(a=30.0, b=20.0, c=12.0, subdivisions=5):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    V = np.asarray(m.vertices, float)
    V = V / np.linalg.norm(V, axis=1, keepdims=True) * [a, b, c]
    return V, np.asarray(m.faces, np.int64)


def ellipsoid_curvature(V, a, b, c):
    """Analytic Gaussian and mean curvature (outward normals: H > 0) of x²/a²+y²/b²+z²/c² = 1."""
    x, y, z = V.T
    s = x * x / a**4 + y * y / b**4 + z * z / c**4
    K = 1.0 / (a * a * b * b * c * c * s * s)
    H = (a * a + b * b + c * c - (x * x + y * y + z * z)) / (2 * (a * b * c) ** 2 * s**1.5)
    return K, H


def ellipsoid_umbilics(a, b, c):
    """The 4 umbilics of an ellipsoid with a > b > c (in the plane of the largest and smallest axes)."""
    x = a * np.sqrt((a * a - b * b) / (a * a - c * c))
    z = c * np.sqrt((b * b - c * c) / (a * a - c * c))
    return np.array([[sx * x, 0.0, sz * z] for sx in (1, -1) for sz in (1, -1)])
