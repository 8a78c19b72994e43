"""The paper's localisation (§3.3, §3.6): candidates around the posed landmark graph, FP node and
canonical-form edge potentials, loopy max-product belief propagation (coarse, then fine)."""

from __future__ import annotations

import numpy as np
from scipy.special import chdtrc, logsumexp  # χ² tail (scipy.stats costs 0.6 s to import)

from ...geometry.spatial import voxel_subsample
from ...names import LANDMARK_NAMES, SUBNASAL
from ..gaussian import log_density, mahalanobis2
from .bp import max_product
from .features import ScanFeatures


def _ball(feat: ScanFeatures, center: np.ndarray, radius: float, spacing: float, cap: int) -> np.ndarray:
    """Vertex ids within ``radius`` of a point, voxel-subsampled, at most ``cap`` (nearest first)."""
    ball = np.asarray(feat.tree.query_ball_point(center[None], float(radius))[0], dtype=np.int64)
    if len(ball) == 0:
        _, j = feat.tree.query(center[None])
        ball = np.array([int(np.asarray(j).ravel()[0])])
    ball = voxel_subsample(feat.vertices, ball, spacing)
    if len(ball) > cap:
        d = np.linalg.norm(feat.vertices[ball] - center, axis=1)
        ball = ball[np.argsort(d)[:cap]]
    return ball


def _bp(feat, model, cands, canon_of, pose, opts):
    """Node (FP + position prior) and edge (canonical relative position) log-potentials over the
    candidate sets, then loopy max-product."""
    r, t = pose
    fps = [feat.fingerprint(c) for c in cands]
    unary = []
    for i, (c, f) in enumerate(zip(cands, fps)):
        off = (feat.vertices[c] - t) @ r - model.graph_points[i]
        unary.append(log_density(f, model.node_mean[i], model.node_cov[i])
                     + log_density(off, model.offset_mean[i], model.offset_cov[i]))
    pos = [canon_of(c) for c in cands]
    pairwise = {}
    for e, (i, j) in enumerate(model.edges):
        rel = pos[j][None, :, :] - pos[i][:, None, :]
        pairwise[(int(i), int(j))] = log_density(rel, model.edge_mean[e], model.edge_cov[e])
    return max_product(unary, pairwise, max_iter=opts.bp_iterations), fps


def bp_localise(feat, model, pose, opts, timer):
    """Candidates around the posed Pa points, canonical form, coarse BP, fine BP."""
    r, t = pose
    cap = int(model.param("max_candidates"))
    expected = (model.graph_points + model.offset_mean) @ r.T + t
    with timer("candidates"):
        # Coarse search regions: the spacing grows with the radius so ~cap candidates cover it.
        spacing = np.maximum(opts.candidate_spacing, model.search_radius * np.sqrt(np.pi / cap))
        cands = [_ball(feat, expected[i], model.search_radius[i], spacing[i], cap)
                 for i in range(len(LANDMARK_NAMES))]
        feat.fingerprint(np.concatenate(cands))
    with timer("canonical"):
        _, sub = feat.tree.query(expected[SUBNASAL][None])
        cf = feat.canonical_form(np.unique(np.concatenate(cands)), int(np.asarray(sub).ravel()[0]),
                                 float(model.param("mds_region_mm")), int(model.param("mds_samples")))
    cache = {}

    def canon_of(ids):
        # scan frame -> template frame (inverse of the pose), so relative positions are
        # comparable with training whatever the scan's pose.
        missing = np.array([v for v in np.unique(ids).tolist() if v not in cache], dtype=np.int64)
        if len(missing):
            p = (cf.place(missing) - t) @ r
            # unreached vertices (another component): far away, so every edge term vetoes them
            cache.update(zip(missing.tolist(), np.nan_to_num(p, nan=1e4)))
        return np.array([cache[int(v)] for v in ids])

    with timer("bp"):
        res, fps = _bp(feat, model, cands, canon_of, pose, opts)
    with timer("refine"):
        fine = [_ball(feat, feat.vertices[c[res.labels[i]]], 1.5 * spacing[i], opts.refine_spacing, cap)
                for i, c in enumerate(cands)]
        fine = [np.union1d(f, [c[res.labels[i]]]) for i, (f, c) in enumerate(zip(fine, cands))]
        res, fps = _bp(feat, model, fine, canon_of, pose, opts)
    return dict(cands=fine, fps=fps, bp=res, rel_stress=cf.rel_stress, expected=expected)


def bp_outputs(feat, model, best, opts):
    """Positions, confidences, vertex ids, posed graph and debug of a BP localisation.

    Confidence per landmark (patch): see :func:`_patch_localise`. Confidence (bp): the BP max-marginal probability mass within ``confidence_radius``
    of the chosen vertex times the node-fit factor (module docstring)."""
    res = best["bp"]
    positions, confidence, vids = {}, {}, {}
    s_dim = len(model.radii)
    for i, nm in enumerate(LANDMARK_NAMES):
        c = best["cands"][i]
        v = int(c[res.labels[i]])
        vids[nm] = v
        positions[nm] = feat.vertices[v].copy()
        b = res.beliefs[i]
        p = np.exp(b - logsumexp(b)) if np.isfinite(b).any() else np.full(len(b), 1.0 / len(b))
        near = np.linalg.norm(feat.vertices[c] - feat.vertices[v], axis=1) <= opts.confidence_radius
        m2 = float(mahalanobis2(best["fps"][i][res.labels[i]], model.node_mean[i], model.node_cov[i]))
        fit = min(1.0, 2.0 * float(chdtrc(s_dim, m2)))
        confidence[nm] = float(np.clip(p[near].sum() * fit, 0.0, 1.0))
    debug = dict(bp_score=res.score, bp_converged=res.converged, n_candidates=[len(c) for c in best["cands"]],
                 rel_stress=best["rel_stress"])
    return positions, confidence, vids, best["expected"], debug

