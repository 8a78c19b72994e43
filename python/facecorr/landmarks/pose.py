"""Rough face pose: rigid ICP of the template's upper face onto the scan (extends paper §3.6).

The paper aligns the landmark graph Pa to four nose points and keeps, of the two 5/6 labellings,
the transform with the smaller D_F (summed closest-point distance of Pa to the scan). On scans
where the FP descriptor cannot separate the subnasal and the alae (our synthetic scans: nostril
holes truncate the geodesic disks) those four points are unreliable, so we *minimise* a trimmed
D_F over the rigid motion instead of only comparing two transforms: trimmed point-to-plane ICP
of a few hundred points of the template's upper face (eyes, nose, forehead, cheeks: the part an
expression moves least) onto the scan. Starts: every nose-point alignment (both labellings) plus
a sweep of rotations about the nose-tip normal (so no pose is assumed); the start with the
smallest trimmed residual after a few iterations is refined.
"""

from __future__ import annotations

import numpy as np

from ..geometry.icp import surface_icp  # noqa: F401  (re-exported: moved to geometry.icp for the mouth search)
from ..geometry.transforms import axis_angle, kabsch, rotation_between, rotation_from_vector


def normal_sweep_starts(tip_tpl: np.ndarray, normal_tpl: np.ndarray, tip_scan: np.ndarray,
                        normal_scan: np.ndarray, n_angles: int = 12):
    """Rigid starts (R, t) mapping the template nose tip and its normal onto the scan's, swept
    over ``n_angles`` rotations about the normal."""
    r0 = rotation_between(normal_tpl, normal_scan)
    out = []
    for k in range(n_angles):
        r = axis_angle(normal_scan, 2 * np.pi * k / n_angles) @ r0
        out.append((r, tip_scan - r @ tip_tpl))
    return out


def _nearest(tree, q, hint):
    """``tree.query(q)`` (nearest points), searched within each point's last match ``hint`` when
    the tree takes hints (:meth:`facecorr.spatial.KDTree.query_hinted`: the same matches)."""
    if hint is not None and hasattr(tree, "query_hinted"):
        return tree.query_hinted(q, hint)
    return tree.query(q)


def _point_to_plane_step(p: np.ndarray, q: np.ndarray, n: np.ndarray):
    """Linearised point-to-plane update (dR, dt) minimising sum ((dR p + dt - q) . n)^2."""
    a = np.hstack([np.cross(p, n), n])  # (k, 6): rows [p x n, n]
    b = np.einsum("ij,ij->i", q - p, n)
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    return rotation_from_vector(x[:3]), x[3:]


def trimmed_icp(points: np.ndarray, tree, r: np.ndarray, t: np.ndarray, iters: int = 20,
                keep: float = 0.8, tol: float = 1e-5, normals: np.ndarray | None = None):
    """Trimmed ICP of points (P, 3) onto the KD-tree's points.

    Each iteration matches every transformed point to its closest scan vertex, keeps the
    ``keep`` fraction with the smallest distances (robust to missing parts and expression) and
    updates the pose: point-to-plane (linearised, fast convergence on smooth surfaces) when the
    scan's unit ``normals`` (N, 3) are given, else point-to-point (Kabsch). Stops when the
    trimmed RMS improves by less than ``tol`` (relative). Returns (R, t, trimmed RMS residual mm,
    closest distances (P,)).
    """
    scan = tree.data
    n_keep = max(6, int(keep * len(points)))
    prev = np.inf
    idx = None
    for _ in range(iters):
        moved = points @ r.T + t
        # each point's match of the last step bounds its search (the same matches, faster)
        d, idx = _nearest(tree, moved, idx)
        idx = np.asarray(idx)
        order = np.argsort(d)[:n_keep]
        rms = float(np.sqrt(np.mean(d[order] ** 2)))
        if prev - rms < tol * max(rms, 1e-9):
            break
        prev = rms
        if normals is None:
            r, t = kabsch(points[order], scan[idx[order]])
        else:
            dr, dt = _point_to_plane_step(moved[order], scan[idx[order]], normals[idx[order]])
            r, t = dr @ r, dr @ t + dt
    moved = points @ r.T + t
    d, _ = _nearest(tree, moved, idx)
    d = np.asarray(d)
    rms = float(np.sqrt(np.mean(np.sort(d)[:n_keep] ** 2)))
    return r, t, rms, d


def fit_pose(points: np.ndarray, tree, starts, coarse_iters: int = 8, fine_iters: int = 40, keep: float = 0.8,
             normals: np.ndarray | None = None):
    """Best rigid pose (R, t, rms, distances) over several starts: a few ICP iterations from
    each, then the best start refined (see :func:`trimmed_icp`)."""
    best = None
    for r0, t0 in starts:
        r, t, rms, _ = trimmed_icp(points, tree, r0, t0, iters=coarse_iters, keep=keep, normals=normals)
        if best is None or rms < best[2]:
            best = (r, t, rms)
    return trimmed_icp(points, tree, best[0], best[1], iters=fine_iters, keep=keep, normals=normals)


def batch_icp(points: np.ndarray, tree, starts, iters: int = 8, keep: float = 0.8,
              normals: np.ndarray | None = None, scales=None):
    """:func:`trimmed_icp` from many starts at once, a fixed number of iterations.

    ``scales`` (S,): start k moves the points as ``x -> scales[k] * R x + t`` (the size of
    each start is held; default 1: rigid).

    All starts advance together: one KD-tree query for every start's moved points per
    iteration and batched 6x6 normal equations (point-to-plane) or batched Kabsch, which is
    ~4x faster than looping :func:`trimmed_icp` over ~50 sweep starts (Python overhead dominates
    a 788-point ICP step). Returns (rms (S,), R (S, 3, 3), t (S, 3)), the trimmed RMS at the
    final poses.
    """
    scan = tree.data
    rs = np.array([np.asarray(r, float) for r, _ in starts])
    ts = np.array([np.asarray(t, float) for _, t in starts])
    n_s, n_p = len(rs), len(points)
    ss = np.ones(n_s) if scales is None else np.asarray(scales, dtype=np.float64).reshape(n_s)
    n_keep = max(6, int(keep * n_p))
    idx = None
    for it in range(iters + 1):
        moved = np.einsum("sij,pj->spi", rs * ss[:, None, None], points) + ts[:, None, :]
        # most starts lie off the surface, where a nearest-point search backtracks far; each
        # point's match of the last step bounds it (the same matches, cheaper)
        flat = moved.reshape(-1, 3)
        d, idx = _nearest(tree, flat, None if idx is None else idx.reshape(-1))
        d, idx = np.asarray(d).reshape(n_s, n_p), np.asarray(idx).reshape(n_s, n_p)
        order = np.argpartition(d, n_keep - 1, axis=1)[:, :n_keep]
        rms = np.sqrt(np.mean(np.take_along_axis(d, order, 1) ** 2, axis=1))
        if it == iters:
            break
        p = np.take_along_axis(moved, order[..., None], 1)
        j = np.take_along_axis(idx, order, 1)
        q = scan[j]
        if normals is None:
            steps = [kabsch(p[k], q[k]) for k in range(n_s)]
            dr, dt = np.array([s[0] for s in steps]), np.array([s[1] for s in steps])
        else:
            n = normals[j]
            a = np.concatenate([np.cross(p, n), n], axis=2)
            b = np.einsum("ski,ski->sk", q - p, n)
            x = np.linalg.solve(np.einsum("ski,skj->sij", a, a) + 1e-9 * np.eye(6),
                                np.einsum("ski,sk->si", a, b)[..., None])[..., 0]
            dr = np.array([rotation_from_vector(w) for w in x[:, :3]])
            dt = x[:, 3:]
        rs = np.einsum("sij,sjk->sik", dr, rs)
        ts = np.einsum("sij,sj->si", dr, ts) + dt
    return rms, rs, ts


def _surface_batch_icp(points, surface, starts, iters, keep, scales=None):
    """:func:`batch_icp` (point-to-plane, ``iters`` updates from every start, no early stop) by
    :func:`surface_icp`, one call per start size: (rms (S,), R (S, 3, 3), t (S, 3))."""
    n_s = len(starts)
    ss = np.ones(n_s) if scales is None else np.asarray(scales, dtype=np.float64).reshape(n_s)
    rms, rs, ts = np.empty(n_s), np.empty((n_s, 3, 3)), np.empty((n_s, 3))
    for s in np.unique(ss):
        ks = np.flatnonzero(ss == s)
        for k, (r, t, e, _) in zip(ks, surface_icp(s * points, surface, [starts[k] for k in ks], iters=iters,
                                                    keep=keep, tol=-np.inf)):
            rms[k], rs[k], ts[k] = e, r, t
    return rms, rs, ts


def fit_poses(points: np.ndarray, tree, starts, n_best: int = 3, min_angle_deg: float = 30.0,
              coarse_iters: int = 8, fine_iters: int = 40, keep: float = 0.8, normals=None,
              coarse_stride: int = 3, scales=None, coarse_scan=None, surface=None):
    """Up to ``n_best`` refined poses [(R, t, rms), ...] from the best coarse starts whose
    rotations differ by more than ``min_angle_deg`` (a face and its upside-down image can fit
    the trimmed residual almost equally well; the caller decides). The coarse stage runs all
    starts together (:func:`batch_icp`) on every ``coarse_stride``-th point (it only ranks the
    starts; nearest-neighbour queries far off the surface, as most starts are, cost ~10x a
    near one), the refinement :func:`trimmed_icp` on all points. ``scales`` (S,): the held
    size of each start (:func:`batch_icp`); then each pose is (R, t, rms, scale). ``coarse_scan``:
    optional (KD-tree, unit normals) of a subsampled scan for the coarse stage (its off-surface
    queries are most of the search's cost and a sparser tree answers them faster). ``surface``:
    the scan's :attr:`~facecorr.geometry.mesh.Mesh.surface` (the same points as ``tree``, with
    ``normals``); the refinement then runs in Rust (:func:`surface_icp`), the poses in parallel."""
    ss = None if scales is None else np.asarray(scales, dtype=np.float64)
    c_tree, c_normals = (tree, normals) if coarse_scan is None else coarse_scan
    coarse_points = points[::max(1, int(coarse_stride))]
    if surface is not None and coarse_scan is None:
        rms, rs, ts = _surface_batch_icp(coarse_points, surface, starts, coarse_iters, keep, ss)
    else:
        rms, rs, ts = batch_icp(coarse_points, c_tree, starts, iters=coarse_iters, keep=keep, normals=c_normals,
                                scales=ss)
    chosen = []
    cos_min = np.cos(np.radians(min_angle_deg))
    for k in np.argsort(rms, kind="stable"):
        if all((np.trace(rs[k].T @ c[0]) - 1) / 2 < cos_min for c in chosen):
            chosen.append((rs[k], ts[k], 1.0 if ss is None else float(ss[k])))
        if len(chosen) >= n_best:
            break
    if surface is not None:
        out = [None] * len(chosen)
        for s in sorted({c[2] for c in chosen}):  # one call per template size
            ks = [k for k, c in enumerate(chosen) if c[2] == s]
            fits = surface_icp(s * points if ss is not None else points, surface, [chosen[k][:2] for k in ks],
                               iters=fine_iters, keep=keep)
            for k, (r, t, rms_k, _) in zip(ks, fits):
                out[k] = (r, t, rms_k) if ss is None else (r, t, rms_k, s)
        return out
    out = []
    for r, t, s in chosen:
        r, t, rms_k, _ = trimmed_icp(s * points if ss is not None else points, tree, r, t, iters=fine_iters,
                                     keep=keep, normals=normals)
        out.append((r, t, rms_k) if ss is None else (r, t, rms_k, s))
    return out


def similarity_icp(points: np.ndarray, tree, r: np.ndarray, t: np.ndarray, iters: int = 30,
                   keep: float = 0.8, tol: float = 1e-5, scale: float = 1.0):
    """Trimmed point-to-point ICP with a uniform scale (Umeyama steps) from the pose
    ``x -> scale * r x + t`` (``scale`` 1: a rigid pose).

    Faces differ in size by several percent, which moves the outer eye corners by 2-3 mm under
    a rigid template; the scale absorbs that. Returns (R (3, 3), scale, t (3,), trimmed RMS mm)
    for ``x -> scale * R x + t``.
    """
    scan = tree.data
    n_keep = max(6, int(keep * len(points)))
    s, prev, rms = float(scale), np.inf, np.inf
    for _ in range(iters):
        d, idx = tree.query(s * points @ r.T + t)
        order = np.argsort(d)[:n_keep]
        rms = float(np.sqrt(np.mean(np.asarray(d)[order] ** 2)))
        if prev - rms < tol * max(rms, 1e-9):
            break
        prev = rms
        try:
            r, s, t = kabsch(points[order], scan[np.asarray(idx)[order]], with_scale=True)
        except ValueError:  # matches collapsed onto a line (not a face): keep the last pose
            break
    return r, s, t, rms
