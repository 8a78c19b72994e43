"""Rigid alignment of the landmark-graph template Pa to the scan; left/right flip by D_F (paper §3.6).

Four nose points are found on the scan: the nose tip (7), the subnasal (8) and two subalare whose
sides are unknown. Pa's points 5-8 (0-based indices 4-7) are aligned rigidly (Kabsch, proper
rotation, no scaling) to the four points in both label configurations of 5/6. The wrong one turns
Pa about the nose (the paper's "flip"), which puts the eye corners off the surface; we keep the
transform whose transformed Pa has the smaller ``D_F`` = sum over Pa's 8 points of the distance
to the closest scan vertex.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry.transforms import kabsch


@dataclass
class GraphAlignment:
    """rotation (3, 3), translation (3,): template frame -> scan frame (x -> R x + t);
    points (8, 3) transformed Pa; order (8,) scan-point index assigned to each label;
    flipped bool: the found points 5/6 were swapped; d_f (2,) D_F of both configurations, mm."""

    rotation: np.ndarray
    translation: np.ndarray
    points: np.ndarray
    flipped: bool
    d_f: np.ndarray


def align_graph(pa: np.ndarray, nose_points: np.ndarray, scan_tree) -> GraphAlignment:
    """Align Pa to the four nose points, resolving the 5/6 ambiguity by D_F.

    Parameters
    ----------
    pa : (8, 3) landmark-graph template in LANDMARK_NAMES order, mm.
    nose_points : (4, 3) found points in the order (side A, side B, nose tip, subnasal), mm;
        sides A/B are the two subalare whose left/right labels are unknown.
    scan_tree : a KD-tree over the scan's vertices (``query(q) -> (dist, idx)``).
    """
    pa = np.asarray(pa, dtype=np.float64)
    nose = np.asarray(nose_points, dtype=np.float64)
    if pa.shape != (8, 3) or nose.shape != (4, 3):
        raise ValueError(f"align_graph: need pa (8, 3) and nose_points (4, 3), got {pa.shape}, {nose.shape}")
    best = None
    d_f = np.empty(2)
    for k, order in enumerate(([0, 1, 2, 3], [1, 0, 2, 3])):
        r, t = kabsch(pa[4:8], nose[order])
        pts = pa @ r.T + t
        dist, _ = scan_tree.query(pts)
        d_f[k] = float(np.sum(dist))
        if best is None or d_f[k] < d_f[best[0]]:
            best = (k, r, t, pts)
    k, r, t, pts = best
    return GraphAlignment(rotation=r, translation=t, points=pts, flipped=bool(k == 1), d_f=d_f)
