"""Nose-tip candidates by protrusion: the pose search's starting points (replaces the paper's
umbilic + FPPCA nose-first start by default; see ``PredictOptions.start_search``).

At a large scale the nose tip is the most protruding point of a face: over a ball of radius
``radius`` (25 mm by default: nose, cheeks and upper lip) it stands 10-12 mm off the ball's
least-squares plane, further than the chin, the brows or the lips. The measure uses only
positions and the plane fit, so it is invariant to the scan's pose and insensitive to
per-vertex noise and small holes. Measured on the first 70 scans of the bu3dfe test split: the
highest-protrusion point was within 8 mm of the true nose tip on every scan, whereas the
umbilic labelled "nose tip" by FPPCA was ~100 mm away on most of them (BENCHMARKS.md,
"Landmarks"). Ears, hair tufts and shoulders of a raw scan can also protrude, so the ``k`` best
separated local maxima are returned and the template ICP decides (:mod:`.pose`).
"""

from __future__ import annotations

import numpy as np

from ..geometry.spatial import voxel_subsample


def smallest_eigenvector(cov: np.ndarray) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of each symmetric 3x3 matrix of ``cov`` (P, 3, 3):
    (P, 3), its sign arbitrary. Where it is not unique: for a rank-one matrix (a ball of two
    points) a unit vector across its line, for a zero matrix (1, 0, 0).

    In closed form (Smith 1961: the eigenvalue from the trigonometric solution of the cubic, the
    vector as the longest cross product of two rows of A − λI), 7x faster than ``np.linalg.eigh``
    (its reference, to 1e-12 in ``tests/test_landmarks_protrusion.py``) on 15k matrices. The
    smallest eigenvalue is well conditioned here even when the two larger ones are equal (a
    ball's disk of points): there the cosine's slope is zero."""
    a, b, c = cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]
    d, e, f = cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]
    q = (a + b + c) / 3.0
    aq, bq, cq = a - q, b - q, c - q
    p = np.sqrt((aq * aq + bq * bq + cq * cq + 2.0 * (d * d + e * e + f * f)) / 6.0)
    det = aq * (bq * cq - f * f) - d * (d * cq - f * e) + e * (d * f - bq * e)
    r = np.clip(det / (2.0 * np.where(p > 0, p, 1.0) ** 3), -1.0, 1.0)
    lam = q + 2.0 * p * np.cos(np.arccos(r) / 3.0 + 2.0 * np.pi / 3.0)
    a, b, c = a - lam, b - lam, c - lam
    # the rows' cross products r0×r1, r0×r2, r1×r2 of A − λI (3 products, 3 coordinates, P)
    cands = np.array([[d * f - e * b, e * d - a * f, a * b - d * d],
                      [d * c - e * f, e * e - a * c, a * f - d * e],
                      [b * c - f * f, f * e - d * c, d * f - b * e]])
    norm2 = np.einsum("kin,kin->kn", cands, cands)
    best = np.argmax(norm2, axis=0)
    cols = np.arange(len(a))
    vec = cands[best, :, cols]
    length = np.sqrt(norm2[best, cols])
    # rank ≤ 1 (a ball of one or two points): the products are rounding; take a unit vector
    # across the matrix's longest row (its line), or (1, 0, 0) when there is none
    ok = length > 1e-10 * (3.0 * q) ** 2
    vec[ok] /= length[ok, None]
    if not ok.all():
        rows = cov[~ok]
        line = rows[np.arange(len(rows)), np.argmax(np.einsum("nij,nij->ni", rows, rows), axis=1)]
        across = np.cross(line, np.eye(3)[np.argmin(np.abs(line), axis=1)])
        size = np.linalg.norm(across, axis=1)
        vec[~ok] = np.where(size[:, None] > 0, across / np.where(size > 0, size, 1.0)[:, None], (1.0, 0.0, 0.0))
    return vec


def ball_protrusion(points: np.ndarray, normals: np.ndarray, radius: float, tree=None):
    """Protrusion of every point over its ball.

    Parameters
    ----------
    points : (P, 3) mm; normals : (P, 3) outward unit normals (only their side is used, to
    orient the plane normal); radius : ball radius, mm; tree : a KD-tree over ``points``
    (``facecorr.spatial.KDTree``), built when None.

    Returns
    -------
    height : (P,) mm, signed distance of each point above the least-squares plane of the points
        in its ball (positive on the side its normal points to);
    plane_normal : (P, 3) unit normal of that plane, oriented like ``normals``;
    count : (P,) points in each ball.
    """
    from ..geometry.spatial import KDTree

    points = np.asarray(points, dtype=np.float64)
    tree = KDTree(points) if tree is None else tree
    # Ball sums of (x, y, z, x², xy, xz, y², yz, z²), summed in the KD-tree's radius search
    # without listing the ~10⁶ (point, neighbour) pairs (a raw 56k-vertex scan: gathering their
    # outer products 1.05 s, a scipy CSR product with the ball-membership matrix 0.18 s plus
    # its import; the CSR product's sums up to rounding). Centred first, so that E[x²] − E[x]² loses
    # nothing wherever the points sit.
    x, y, z = (points - points.mean(axis=0)).T
    count, sums = tree.ball_sums(points, float(radius), np.stack([x, y, z, x * x, x * y, x * z, y * y, y * z, z * z],
                                                                 axis=1))
    centroid = sums[:, :3] / count[:, None]
    second = sums[:, 3:] / count[:, None]
    cov = np.empty((len(points), 3, 3))
    for (a, b), col in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)), range(6)):
        cov[:, a, b] = cov[:, b, a] = second[:, col] - centroid[:, a] * centroid[:, b]
    plane_normal = smallest_eigenvector(cov)
    plane_normal *= np.where(np.einsum("ij,ij->i", plane_normal, normals) < 0, -1.0, 1.0)[:, None]
    height = np.einsum("ij,ij->i", (points - points.mean(axis=0)) - centroid, plane_normal)
    return height, plane_normal, count


def nose_tip_candidates(vertices: np.ndarray, normals: np.ndarray, k: int = 4, radius: float = 25.0,
                        spacing: float = 3.0, min_separation: float = 20.0, keep: np.ndarray | None = None,
                        median_k: int = 1, extreme_axis: bool = False):
    """Up to ``k`` nose-tip candidates, best first.

    Parameters
    ----------
    vertices : (N, 3) mm; normals : (N, 3) unit outward vertex normals.
    k : number of candidates; radius : protrusion scale, mm; spacing : voxel subsampling of the
    scan before the measure, mm; min_separation : candidates are local maxima at least this far
    apart, mm.
    keep : optional (N,) bool, the vertices that take part (both as candidates and in the balls'
        planes), e.g. those of the scan's large pieces: a glasses frame floating in front of the
        eyes tilts the plane of the nose tip's ball (measured: the tip's protrusion drops from
        ~10 to 2-5 mm) and its pieces protrude themselves.
    median_k : the height of a point is the median over its ``median_k`` nearest subsampled
        points (itself included; 1 = its own): a spike of hair or noise stands out alone, a nose
        tip is a cap ~10 mm wide whose neighbours protrude almost as much.
    extreme_axis : also return the point furthest out along the scan's axis of least variance
        (:func:`_outward_axis`, the direction the face looks to), after the ``k`` others, unless it
        lies within ``min_separation`` of one of them. A second opinion for when the ball fails:
        glasses leave a hole over the nose bridge or a frame in front of it, and the tip's ball
        plane tilts or rises (2-4 mm of protrusion where a nose has ~9); a small face's nose
        fills less of the ball. Measured: the extreme point lies within 12 mm of the true tip on
        84 of 98 `ood_test`, 40 of 42 `ood_holdout` and 68 of 70 in-model scans, and on every
        held-back scan whose tip the ball missed (`benches/nose_tip_candidates.py`; BENCHMARKS.md,
        "Out of model, eighth pass").

    Returns
    -------
    list of (vertex id, height mm, (3,) plane normal), by decreasing height (the ``extreme_axis``
    point last, with its own height). Balls with fewer
    than a quarter of the median point count (scan borders, islands) are skipped: their plane
    is unreliable.
    """
    ids = np.arange(len(vertices)) if keep is None else np.flatnonzero(keep)
    ids = ids[voxel_subsample(vertices[ids], np.arange(len(ids)), spacing)]
    pts = vertices[ids]
    height, plane_normal, count = ball_protrusion(pts, normals[ids], radius)
    ok = count >= max(10, 0.25 * np.median(count))
    if median_k > 1 and len(pts) > 1:
        from ..geometry.spatial import KDTree

        _, nb = KDTree(pts).query(pts, k=min(int(median_k), len(pts)))
        height = np.median(height[nb], axis=1)
    out = []
    for o in np.argsort(-height):
        if len(out) >= k:
            break
        if not ok[o]:
            continue
        p = vertices[ids[o]]
        if all(np.linalg.norm(p - vertices[v]) > min_separation for v, _, _ in out):
            out.append((int(ids[o]), float(height[o]), plane_normal[o].copy()))
    if extreme_axis and len(pts) >= 3 and ok.any():
        axis = _outward_axis(pts, normals[ids])
        o = np.flatnonzero(ok)[int(np.argmax((pts[ok] - pts.mean(axis=0)) @ axis))]
        p = vertices[ids[o]]
        if all(np.linalg.norm(p - vertices[v]) > min_separation for v, _, _ in out):
            out.append((int(ids[o]), float(height[o]), plane_normal[o].copy()))
    return out


def _outward_axis(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(3,) unit axis of least variance of ``points`` (P, 3), on the side ``normals`` point to on
    average: a face scan's viewing direction, along which the nose tip stands out furthest."""
    _, vec = np.linalg.eigh(np.cov((points - points.mean(axis=0)).T))
    axis = vec[:, 0]
    return axis if float(np.sum(normals @ axis)) >= 0 else -axis
