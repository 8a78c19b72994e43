"""The paper's start (§3.4-3.6): umbilics, FPPCA labels, the nose-first search and the landmark-
graph alignment with the flip test, then the template ICP from those alignments.

:func:`paper_pose` returns the rigid pose template -> scan that :mod:`.localise` (or the default
patch localisation) refines; see :mod:`facecorr.landmarks.predict` for the stages and options.
"""

from __future__ import annotations

import numpy as np

from ...errors import LandmarkError
from ...geometry.spatial import voxel_subsample
from ...geometry.transforms import kabsch
from ...names import L_SUBALARE, LANDMARK_NAMES, NOSE_TIP, R_SUBALARE, SUBNASAL
from ..gaussian import log_density
from ..pose import fit_poses, normal_sweep_starts
from .alignment import align_graph
from .features import ScanFeatures


def _fppca(feat: ScanFeatures, clf, ids: np.ndarray):
    """(labels (n, L) bool, medoid distances (n, L)) of vertex ids."""
    fp = feat.fingerprint(ids)
    return clf.label(fp), clf.medoid_distance(fp)


def _dist_logp(model, a: int, b: int, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """(len(pa), len(pb)) Gaussian log-potential of the Euclidean distance between nose points."""
    d = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
    mu, sd = model.nose_pair_mean[a, b], model.nose_pair_std[a, b]
    return -0.5 * ((d - mu) / sd) ** 2


def _labelled_or_best(ids, labels, ll, cls, k_extra=5):
    """Candidates for class cls: the vertices FPPCA labels cls, plus the k_extra with the best
    node log-likelihood (so one unlucky ellipsoid does not end the search)."""
    m = labels[:, cls].copy()
    m[np.argsort(-ll)[:k_extra]] = True
    return ids[m], ll[m]


def _nose_points(feat: ScanFeatures, model, start: int, opts) -> list:
    """Nose hypotheses [(ids (4,) = side A, side B, tip, subnasal vertex ids, flags), ...] from a start.

    Paper §3.5 with one documented change: instead of taking, per class, the labelled vertex
    nearest the medoid, the tip/subnasal pair and then each side's subalare are chosen jointly,
    maximising the FP node log-likelihoods plus Gaussian log-potentials of their Euclidean
    distances (learned, rotation invariant, left/right pooled). The FPPCA labels still define
    the candidate sets and the k-means split into sides.
    """
    clf = model.classifier
    flags = []
    r = float(model.param("nose_search_radius_mm"))
    disk = voxel_subsample(feat.vertices, feat.geodesic_disk(start, r), opts.circle_spacing)
    disk = np.union1d(disk, [start])
    fp = feat.fingerprint(disk)
    lab = clf.label(fp)
    ll_t = log_density(fp, model.node_mean[NOSE_TIP], model.node_cov[NOSE_TIP])
    ll_s = log_density(fp, model.node_mean[SUBNASAL], model.node_cov[SUBNASAL])
    if not lab[:, NOSE_TIP].any():
        flags.append("nose_tip_unlabelled")
    if not lab[:, SUBNASAL].any():
        flags.append("subnasal_unlabelled")
    tips, llt = _labelled_or_best(disk, lab, ll_t, NOSE_TIP)
    subs, lls = _labelled_or_best(disk, lab, ll_s, SUBNASAL)
    score = llt[:, None] + lls[None, :] + _dist_logp(model, 2, 3, feat.vertices[tips], feat.vertices[subs])
    score[tips[:, None] == subs[None, :]] = -np.inf
    a, b = np.unravel_index(np.argmax(score), score.shape)
    tip, sub = int(tips[a]), int(subs[b])
    r2 = float(model.param("subnasal_search_radius_mm"))
    disk2 = voxel_subsample(feat.vertices, feat.geodesic_disk(sub, r2), opts.circle_spacing)
    fp2 = feat.fingerprint(disk2)
    lab2 = clf.label(fp2)
    # Re-choose the tip around the subnasal too: a start on the upper lip can leave the true tip
    # outside the first circle, and the circle around the subnasal always holds it.
    tips2, llt2 = _labelled_or_best(disk2, lab2, log_density(fp2, model.node_mean[NOSE_TIP], model.node_cov[NOSE_TIP]), NOSE_TIP)
    tips2, llt2 = np.concatenate([tips2, tips]), np.concatenate([llt2, llt])
    sc_t = llt2 + _dist_logp(model, 2, 3, feat.vertices[tips2], feat.vertices[[sub]])[:, 0]
    sc_t[tips2 == sub] = -np.inf
    # Several tips at least 6 mm apart, each completed with its alae and ranked by the joint
    # nose score (node log-likelihoods + all six pairwise distance terms); the best n_tips become
    # hypotheses and the full-graph BP score decides between them.
    tip_list = []
    for k in np.argsort(-sc_t):
        if not np.isfinite(sc_t[k]) or len(tip_list) >= 4 * int(opts.n_tips):
            break
        if all(np.linalg.norm(feat.vertices[tips2[k]] - feat.vertices[t]) > 6.0 for t, _ in tip_list):
            tip_list.append((int(tips2[k]), float(sc_t[k])))
    if not tip_list:
        tip_list = [(tip, 0.0)]
    scored = []
    for t, sct in tip_list:
        ids, sca = _alae(feat, model, t, sub, disk2, fp2, lab2, flags)
        sides = feat.vertices[ids[:2]]
        scored.append((sct + sca + float(_dist_logp(model, 0, 1, sides[:1], sides[1:])[0, 0]), ids))
    scored.sort(key=lambda x: -x[0])
    return [(ids, flags) for _, ids in scored[: int(opts.n_tips)]]


def _alae(feat, model, tip, sub, disk2, fp2, lab2, flags):
    """The two subalare (sides unknown) around the subnasal for a given tip (paper: FPPCA labels
    5/6, k-means into two sides, then one point per side)."""
    ll_a = np.maximum(log_density(fp2, model.node_mean[R_SUBALARE], model.node_cov[R_SUBALARE]),
                      log_density(fp2, model.node_mean[L_SUBALARE], model.node_cov[L_SUBALARE]))
    side = lab2[:, R_SUBALARE] | lab2[:, L_SUBALARE]
    side[np.argsort(-ll_a)[:10]] = True
    if not (lab2[:, R_SUBALARE] | lab2[:, L_SUBALARE]).any():
        flags.append("subalare_unlabelled")
    pts_ids, pts_ll = disk2[side], ll_a[side]
    pts = feat.vertices[pts_ids]
    # k-means on 3-D positions: the two alae are on either side of the subnasal.
    init = _two_side_init(pts, feat.vertices[tip], feat.vertices[sub])
    from scipy.cluster.vq import kmeans2  # the paper's start only: imported when used

    _, assign = kmeans2(pts, init, minit="matrix", seed=0)
    if (np.bincount(assign, minlength=2) == 0).any():
        flags.append("subalare_one_sided")
        assign = (np.linalg.norm(pts - init[1], axis=1) < np.linalg.norm(pts - init[0], axis=1)).astype(int)
    ptip, psub = feat.vertices[[tip]], feat.vertices[[sub]]
    chosen, total = [], 0.0
    for k in range(2):
        m = assign == k
        if not m.any():
            chosen.append(int(pts_ids[0]))
            total -= 1e6
            continue
        p = pts[m]
        sc = (pts_ll[m] + _dist_logp(model, 0, 2, p, ptip)[:, 0] + _dist_logp(model, 0, 3, p, psub)[:, 0])
        chosen.append(int(pts_ids[m][np.argmax(sc)]))
        total += float(np.max(sc))
    return np.array([chosen[0], chosen[1], tip, sub]), total


def _two_side_init(pts, tip, sub):
    """Deterministic k-means start: the extreme points along the principal direction of the
    labelled points orthogonal to the tip-subnasal line."""
    axis = tip - sub
    axis = axis / (np.linalg.norm(axis) + 1e-12)
    c = pts - pts.mean(0)
    c = c - np.outer(c @ axis, axis)
    if len(pts) < 2 or np.allclose(c, 0):
        return np.vstack([pts[0], pts[-1]]).astype(float)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    s = c @ vt[0]
    return np.vstack([pts[np.argmin(s)], pts[np.argmax(s)]]).astype(float)


def _pose(feat, model, hyps, opts):
    """Rigid pose template -> scan: trimmed ICP from the nose-point alignments (both 5/6
    labellings, paper §3.6) and a sweep about the nose-tip normal at each distinct tip.

    ``opts.paper_pose_score="template"``: the starts are grouped by their nose tip (tips within
    3 mm are one), each group keeps its 2 best ICP poses (a face and its upside-down image) and
    the whole template's residual decides among all of them, as in the default start (start.py):
    the upper face alone fits a face upside down almost as well (eyes on the mouth, the nose tip
    in place), and pooling every tip's starts let a wrong tip's poses crowd out the right one's
    (14 of the 25 failures on the 350 test scans; BENCHMARKS.md, "The paper's method at the
    paper's numbers"). ``"fp"``: the 3 best poses of all starts pooled, and among those that fit
    about as well as the best, the one whose posed landmarks' FP descriptors are likeliest."""
    groups, d_f = [], {}  # [(tip vertex, [starts])]

    def group_of(tip):
        for g in groups:
            if np.linalg.norm(feat.vertices[tip] - feat.vertices[g[0]]) <= 3.0:
                return g[1]
        groups.append((tip, []))
        return groups[-1][1]

    for ids in hyps:
        al = align_graph(model.graph_points, feat.vertices[np.array(ids)], feat.tree)
        d_f[ids] = al.d_f
        g = group_of(ids[2])
        for order in ([0, 1, 2, 3], [1, 0, 2, 3]):
            g.append(kabsch(model.graph_points[4:8], feat.vertices[np.array(ids)[order]]))
    tpl_tip = model.graph_points[NOSE_TIP]
    for tip, g in groups[: int(opts.sweep_tips)]:
        g += normal_sweep_starts(tpl_tip, model.icp_tip_normal, feat.vertices[tip], feat.tip_normal(tip),
                                 int(opts.sweep_angles))
    full = None
    if opts.paper_pose_score == "template":
        from ..start import _pose_score, _template_surface_points

        try:
            full = _template_surface_points(model, float(opts.pose_score_spacing))
        except LandmarkError:
            full = None  # a model of another template: the FP choice below
    if full is not None:
        poses = [p for _, g in groups for p in fit_poses(model.icp_points, feat.tree, g, n_best=2, normals=feat.normals)]
        scores = [_pose_score(full, feat.tree, r, t, feat.normals, opts.pose_score, 1.0, int(opts.pose_score_iters))
                  for r, t, _ in poses]
        r, t, rms = poses[int(np.argmin(scores))]
        return r, t, rms, d_f
    poses = fit_poses(model.icp_points, feat.tree, [st for _, g in groups for st in g], normals=feat.normals)
    best_rms = min(p[2] for p in poses)
    best = None
    for r, t, rms in poses:
        if rms > 1.5 * best_rms + 0.5:
            continue
        expected = (model.graph_points + model.offset_mean) @ r.T + t
        _, vid = feat.tree.query(expected)
        fp = feat.fingerprint(np.asarray(vid, dtype=np.int64))
        score = sum(float(log_density(fp[i], model.node_mean[i], model.node_cov[i])) for i in range(len(fp)))
        if best is None or score > best[3]:
            best = (r, t, rms, score)
    return best[0], best[1], best[2], d_f


def paper_pose(mesh, feat, model, opts, timer, name, flags):
    """Paper §3.4-3.6 start: umbilics, FPPCA labels, nose-first search, graph alignment in both
    5/6 labellings, then the template ICP from those alignments (:func:`_pose`). Returns
    (R, t, trimmed rms mm, debug dict); appends reasons for doubt to ``flags``."""
    with timer("umbilics"):
        from ...geometry.curvature import umbilics

        umb = np.asarray(umbilics(mesh.vertices, mesh.faces), dtype=np.int64)
    if len(umb) == 0:
        raise LandmarkError(f"{name}: no umbilics found: not a face surface (too small or flat?)")
    n_umb = len(umb)
    if opts.fp_border_check:
        # An FP descriptor measures whole geodesic disks; near the scan's outer border its larger
        # disks are cut off, which shrinks their area as a protruding tip's does: on the scans
        # where the paper's start failed, every umbilic FPPCA ranked "nose tip" lay ~8 mm from
        # the crop border, ~100 mm from the nose (BENCHMARKS.md, "The paper's method at the paper's
        # numbers"). Umbilics nearer the border than the largest radius have no complete
        # descriptor: they are no starts.
        border = mesh.outer_boundary
        if len(border):
            from ...geometry.spatial import KDTree

            d_border = np.asarray(KDTree(mesh.vertices[border]).query(mesh.vertices[umb])[0])
            inside = d_border >= float(np.max(model.radii))
            if inside.any():
                umb = umb[inside]
            else:
                flags.append("no_umbilic_inside_border")
    with timer("fppca"):
        lab, dist = _fppca(feat, model.classifier, umb)
    # Start hypotheses (paper: the umbilic labelled nose tip nearest its medoid). The nose circle
    # of radius r around either the nose tip or the subnasal holds both, so we also start from
    # the best subnasal umbilics; every resulting nose hypothesis seeds the pose search.
    starts = []
    for cls in (NOSE_TIP, SUBNASAL):
        order = np.argsort(dist[:, cls])
        labelled = order[lab[order, cls]]
        if len(labelled) == 0:
            flags.append(f"no_umbilic_labelled_{LANDMARK_NAMES[cls]}")
            labelled = order
        for k in labelled[: max(1, int(opts.n_starts))]:
            if int(umb[k]) not in starts:
                starts.append(int(umb[k]))
    hyps = {}
    with timer("nose"):
        for s in starts:
            try:
                for ids, fl in _nose_points(feat, model, s, opts):
                    hyps.setdefault(tuple(int(i) for i in ids), fl)
            except ValueError as e:  # a start on an island or a tiny region: try the next one
                flags.append(f"start_failed:{e}")
    if not hyps:
        raise LandmarkError(f"{name}: no usable nose region found (no face, or a hole over the nose?)")
    with timer("pose"):
        r, t, rms, d_f = _pose(feat, model, list(hyps), opts)
    for fl in hyps.values():
        flags += fl
    return r, t, rms, dict(nose_hypotheses=list(hyps), d_f=d_f, n_umbilics=n_umb, n_start_umbilics=len(umb),
                             starts=starts)

