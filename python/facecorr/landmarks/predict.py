"""Landmark prediction on an untouched scan (paper §3.2-3.6, and the faster, more accurate default).

Two start searches (``start_search``) and two localisations (``localise``) combine:

* default, ``protrusion`` + ``patch`` (~1 s per 35k-vertex scan): the most protruding points
  (:mod:`.protrusion`) seed a rigid ICP of the template's upper face (sweep about the protrusion
  plane normal); the whole-template residual picks among the best poses; a uniform scale is
  fitted; each landmark is carried by a local ICP of the template's own surface around it.
* the paper, ``paper`` + ``bp`` (~8 s): umbilics, FPPCA labels, nose-first search, graph
  alignment with the flip test, then FP node + canonical-form edge potentials and loopy BP.
  Measured side by side on the bu3dfe test split in BENCHMARKS.md ("Landmarks").

Stages (their wall times are returned in ``LandmarkResult.timings_s``):

``prepare``     geodesic solver + KD-tree over the scan (compiled core).
``starts``      (protrusion) nose-tip candidates and the rotation sweep about each.
``patches``     (patch) similarity refinement and the per-landmark template-patch fits.
``prepare``     geodesic solver + KD-tree over the scan (compiled core).
``umbilics``    umbilic vertices (``facecorr.curvature.umbilics``): the samples of §3.4.
``fppca``       FP descriptors at the umbilics, PCA projection, ellipsoid labels.
``nose``        §3.5: start at the umbilic closest (PCA space) to the nose-tip medoid among those
                labelled nose tip; FPPCA on the geodesic circle of radius r around it; nose tip /
                subnasal = the labelled vertices closest to their medoids; FPPCA on the circle
                around the subnasal, vertices labelled 5 or 6 split by k-means (k = 2, fixed seed)
                into the two sides; each side's point = the vertex nearest its centroid.
``align``       §3.6: Pa's nose points aligned rigidly to the four points in both 5/6 labellings;
                the labelling with the smaller D_F wins.
``candidates``  search regions: scan vertices within ``search_radius[i]`` (Euclidean) of each
                aligned Pa point, voxel-subsampled (spacing grown with the radius so that about
                ``max_candidates`` cover the region, at least ``candidate_spacing`` mm); FP at each.
``canonical``   canonical form (FMM geodesics + SMACOF, :mod:`.mds`) of the candidates, rotated
                into the template frame by the inverse of the ``align`` transform.
``bp``          loopy max-product BP with the Gaussian node (FP) and edge (relative canonical
                position) log-potentials.
``refine``      a second BP over dense candidates (``refine_spacing`` mm) within 1.5 coarse
                spacings of each coarse winner (coarse-to-fine; the paper uses a single pass).

Circles are subsampled to ``circle_spacing`` mm before FPPCA (a 25 mm geodesic circle holds
~2000 vertices of a 1 mm scan; FP at every one is the dominant cost and neighbours 1 mm apart
carry the same label). When several nose-tip starts are plausible, the ``n_starts`` best umbilics
are tried and the hypothesis with the best BP score wins (robustness on raw scans with hair).

Confidence per landmark (patch): see :func:`_patch_localise`. Confidence (bp): the BP max-marginal probability mass (softmax of the beliefs) within
``confidence_radius`` mm of the chosen vertex, times a node-fit factor
``min(1, 2 * chi2.sf(m2, S))`` where m2 is the squared Mahalanobis distance of the chosen
vertex's FP to the landmark's learned Gaussian (1 for a typical descriptor, small for an
implausible one). Flags name the reasons for doubt.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, chdtri, logsumexp  # χ² tail and its inverse (scipy.stats costs 0.6 s to import)

from ..errors import LandmarkError
from ..names import LANDMARK_NAMES
from .alignment import align_graph, kabsch
from .bp import max_product
from .features import ScanFeatures, voxel_subsample
from .gaussian import log_density, mahalanobis2

NOSE_TIP, SUBNASAL, R_SUBALARE, L_SUBALARE = 6, 7, 4, 5

#: Prediction settings not stored in the model (they do not depend on training).
PREDICT_DEFAULTS = {
    "start_search": "protrusion", # "protrusion" (default) or "paper" (umbilics + FPPCA + nose search)
    "n_tip_candidates": 4,        # protrusion maxima tried as nose tips
    "protrusion_radius": 25.0,    # mm, scale of the protrusion measure
    "min_protrusion": 4.0,        # mm, refuse a scan whose highest protrusion is lower (no nose)
    "n_poses": 5,                 # distinct coarse poses refined and scored by the whole template
    "localise": "patch",          # "patch" (default: local template fits) or "bp" (paper: FP + BP)
    "patch_radius": 20.0,         # mm, template patch around the subalare and the subnasal
    "tip_patch_radius": 25.0,     # mm, the nose tip's (its 20 mm patch slides along the ridge)
    "eye_patch_radius": 25.0,     # mm, the eye corners' (outer corners 3.04/3.06 -> 2.74/2.82 mm)
    "circle_spacing": 3.0,        # mm, subsampling of the geodesic search circles
    "candidate_spacing": 1.5,     # mm, finest subsampling of the coarse BP search regions
    "refine_spacing": 1.0,        # mm, candidates of the fine BP pass
    "n_starts": 3,                # nose-tip (and subnasal) start umbilics
    "n_tips": 2,                  # nose-tip choices per start
    "sweep_tips": 2,              # distinct tips with a rotation sweep about their normal
    "sweep_angles": 12,           # rotations per sweep
    "confidence_radius": 4.0,     # mm
    "low_confidence": 0.3,        # flag below this
    "bp_iterations": 60,
    "retry": True,                # redo a self-flagged failure with the wider search below
}

#: The wider start search used when a first prediction fails its own checks (graph off the
#: surface, poor face fit): more umbilic starts (paper start; 6 of 10 such failures corrected,
#: ~10 s per retry) or more protrusion candidates and a finer sweep (default start; 19 of the
#: 350 bu3dfe test scans retried, ~1 s each). Kept out of the first pass for speed.
RETRY_OVERRIDES = {"n_starts": 8, "sweep_tips": 4, "n_tips": 3, "n_tip_candidates": 10, "sweep_angles": 16}

#: Flags that mean "the whole graph is probably misplaced" (31 of 34 such failures flagged, no
#: false alarm on 36 good scans, BENCHMARKS.md).
FAILURE_FLAGS = ("graph_off_surface", "poor_face_fit")


def _failed(result) -> bool:
    return any(f.startswith(FAILURE_FLAGS) for f in result.flags)


@dataclass
class LandmarkResult:
    """positions dict name -> (3,) mm (scan frame); confidence dict name -> [0, 1];
    flags list of str (reasons for doubt); timings_s dict stage -> seconds;
    vertex_ids dict name -> chosen scan vertex; debug dict (intermediate results)."""

    positions: dict
    confidence: dict
    flags: list
    timings_s: dict
    vertex_ids: dict = field(default_factory=dict)
    debug: dict = field(default_factory=dict)

    def as_array(self) -> np.ndarray:
        """(8, 3) positions in LANDMARK_NAMES order, mm."""
        return np.array([self.positions[n] for n in LANDMARK_NAMES])


class _Timer:
    def __init__(self):
        self.t = {}

    def __call__(self, name):
        timer = self

        class _C:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                timer.t[name] = timer.t.get(name, 0.0) + time.perf_counter() - self.t0
        return _C()


def _fppca(feat: ScanFeatures, clf, ids: np.ndarray):
    """(labels (n, L) bool, medoid distances (n, L)) of vertex ids."""
    fp = feat.fingerprint(ids)
    return clf.label(fp), clf.medoid_distance(fp)


def _closest_labelled(ids, labels, dist, cls):
    """The id labelled ``cls`` with the smallest medoid distance, or None."""
    m = labels[:, cls]
    if not m.any():
        return None
    k = np.flatnonzero(m)[np.argmin(dist[m, cls])]
    return int(ids[k])


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
    disk = voxel_subsample(feat.vertices, feat.geodesic_disk(start, r), opts["circle_spacing"])
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
    disk2 = voxel_subsample(feat.vertices, feat.geodesic_disk(sub, r2), opts["circle_spacing"])
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
        if not np.isfinite(sc_t[k]) or len(tip_list) >= 4 * int(opts["n_tips"]):
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
    return [(ids, flags) for _, ids in scored[: int(opts["n_tips"])]]


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
    return max_product(unary, pairwise, max_iter=opts["bp_iterations"]), fps


def _pose(feat, model, hyps, opts):
    """Rigid pose template -> scan: trimmed ICP from the nose-point alignments (both 5/6
    labellings, paper §3.6) and a sweep about the nose-tip normal at each distinct tip."""
    from .pose import fit_poses, normal_sweep_starts

    starts, tips, d_f = [], [], {}
    for ids in hyps:
        al = align_graph(model.graph_points, feat.vertices[np.array(ids)], feat.tree)
        d_f[ids] = al.d_f
        for order in ([0, 1, 2, 3], [1, 0, 2, 3]):
            r, t = kabsch(model.graph_points[4:8], feat.vertices[np.array(ids)[order]])
            starts.append((r, t))
        if all(np.linalg.norm(feat.vertices[ids[2]] - feat.vertices[k]) > 3.0 for k in tips):
            tips.append(ids[2])
    tpl_tip = model.graph_points[NOSE_TIP]
    for tip in tips[: int(opts["sweep_tips"])]:
        n = feat.tip_normal(tip)
        starts += normal_sweep_starts(tpl_tip, model.icp_tip_normal, feat.vertices[tip], n, int(opts["sweep_angles"]))
    poses = fit_poses(model.icp_points, feat.tree, starts, normals=feat.normals)
    # Among the poses that fit the surface about as well as the best one, keep the one whose
    # posed landmarks look most like landmarks (FP node log-likelihoods at the nearest vertices):
    # this separates a face from its upside-down image, which ICP alone can confuse.
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


def _localise(feat, model, pose, opts, timer):
    """Candidates around the posed Pa points, canonical form, coarse BP, fine BP."""
    r, t = pose
    cap = int(model.param("max_candidates"))
    expected = (model.graph_points + model.offset_mean) @ r.T + t
    with timer("candidates"):
        # Coarse search regions: the spacing grows with the radius so ~cap candidates cover it.
        spacing = np.maximum(opts["candidate_spacing"], model.search_radius * np.sqrt(np.pi / cap))
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
        fine = [_ball(feat, feat.vertices[c[res.labels[i]]], 1.5 * spacing[i], opts["refine_spacing"], cap)
                for i, c in enumerate(cands)]
        fine = [np.union1d(f, [c[res.labels[i]]]) for i, (f, c) in enumerate(zip(fine, cands))]
        res, fps = _bp(feat, model, fine, canon_of, pose, opts)
    return dict(cands=fine, fps=fps, bp=res, rel_stress=cf.rel_stress, expected=expected)


def predict_landmarks(mesh, model=None, **options) -> "LandmarkResult":
    """Predict the 8 landmarks of a face scan.

    Parameters
    ----------
    mesh : facecorr.mesh.Mesh (mm, any pose, cropped or raw).
    model : LandmarkModel, a path, or None for the packaged default.
    options : overrides of :data:`PREDICT_DEFAULTS`.

    Returns
    -------
    LandmarkResult (positions in mm, scan frame).

    Raises
    ------
    LandmarkError : no face-like structure to start from (no umbilics, no nose-tip candidate).
    """
    from .model import LandmarkModel, load_model

    opts = dict(PREDICT_DEFAULTS)
    unknown = set(options) - set(opts)
    if unknown:
        raise TypeError(f"predict_landmarks: unknown options {sorted(unknown)}")
    opts.update(options)
    if not isinstance(model, LandmarkModel):
        model = load_model(model)
    first = _predict_once(mesh, model, opts)
    if not (opts["retry"] and _failed(first)):
        return first
    second = _predict_once(mesh, model, {**opts, **RETRY_OVERRIDES})
    best = second if not _failed(second) else first
    best.flags = list(dict.fromkeys(best.flags + ["retried_wider_search"]))
    best.timings_s = {k: first.timings_s.get(k, 0.0) + second.timings_s.get(k, 0.0)
                      for k in set(first.timings_s) | set(second.timings_s)}
    return best


def _bp_outputs(feat, model, best, opts):
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
        near = np.linalg.norm(feat.vertices[c] - feat.vertices[v], axis=1) <= opts["confidence_radius"]
        m2 = float(mahalanobis2(best["fps"][i][res.labels[i]], model.node_mean[i], model.node_cov[i]))
        fit = min(1.0, 2.0 * float(chdtrc(s_dim, m2)))
        confidence[nm] = float(np.clip(p[near].sum() * fit, 0.0, 1.0))
    debug = dict(bp_score=res.score, bp_converged=res.converged, n_candidates=[len(c) for c in best["cands"]],
                 rel_stress=best["rel_stress"])
    return positions, confidence, vids, best["expected"], debug


_PATCH_CACHE: dict = {}

#: A patch whose displacement from the global prediction has a squared Mahalanobis distance
#: (learned offset covariance) above this (chi2, 3 dof, p = 0.001) is rejected.
RUNAWAY_M2 = float(chdtri(3, 0.001))


def _packaged_template(model):
    """The packaged template; LandmarkError if the model's Pa is not its landmarks."""
    from ..template import load_template

    tpl = load_template()
    lm = tpl.vertices[tpl.landmark_ids]
    if lm.shape != model.graph_points.shape or np.abs(lm - model.graph_points).max() > 1e-3:
        raise LandmarkError("the model's landmark graph is not the packaged template's: "
                            "use localise='bp' with this model")
    return tpl


def _template_surface_points(model, spacing: float = 4.0) -> np.ndarray:
    """(P, 3) the packaged template's vertices voxel-subsampled at ``spacing`` mm (~1,900)."""
    key = (model.graph_points.tobytes(), "surface", float(spacing))
    if key not in _PATCH_CACHE:
        tpl = _packaged_template(model)
        _PATCH_CACHE[key] = tpl.vertices[voxel_subsample(tpl.vertices, np.arange(tpl.n_vertices), spacing)]
    return _PATCH_CACHE[key]


def _template_patches(model, radius: float) -> list:
    """Per landmark, the packaged template's vertices (P_i, 3) within ``radius`` mm of its Pa
    point (template frame, mm). Raises LandmarkError if the model's Pa is not this template's."""
    key = (model.graph_points.tobytes(), float(radius))
    if key not in _PATCH_CACHE:
        tpl = _packaged_template(model)
        lm = tpl.vertices[tpl.landmark_ids]
        _PATCH_CACHE[key] = tuple(tpl.vertices[np.linalg.norm(tpl.vertices - p, axis=1) < radius] for p in lm)
    return list(_PATCH_CACHE[key])


def _patch_localise(feat, model, pose, opts):
    """Default localisation: the template's own surface around each landmark, fitted locally.

    1. the rigid pose gains a uniform scale (:func:`.pose.similarity_icp` of the upper face);
    2. per landmark, the template patch within ``patch_radius`` mm of it (``eye_patch_radius`` at
       the eye corners, ``tip_patch_radius`` at the nose tip; radii chosen on 175 training-split
       scans among 10-40 mm) (scaled) is fitted by
       trimmed point-to-plane ICP from that pose, and the landmark (plus its learned mean
       offset) is carried along; the nearest scan vertex is the answer.
    The patch holds the shape of the eye corner, ala or nose tip over ~20 mm, far more than an
    8-number FP descriptor, and the local rigid fit absorbs the expression and identity
    differences the global pose leaves (measured in BENCHMARKS.md, "Landmarks").

    Confidence: ``min(1, 2 chi2.sf(m2, 3))`` of the patch's displacement from the global
    prediction under the learned offset covariance (a patch that had to travel far is doubtful)
    times ``min(1, (2 mm / patch rms)^2)`` (a patch that does not fit the surface is doubtful).
    """
    from .pose import similarity_icp, trimmed_icp

    r, t = pose
    r, scale, t, _ = similarity_icp(model.icp_points, feat.tree, r, t)
    flags = [] if 0.75 < scale < 1.33 else [f"implausible_face_scale:{scale:.2f}x template"]
    scale = float(np.clip(scale, 0.75, 1.33))
    patches = _template_patches(model, float(opts["patch_radius"]))
    patches[NOSE_TIP] = _template_patches(model, float(opts["tip_patch_radius"]))[NOSE_TIP]
    patches[:4] = _template_patches(model, float(opts["eye_patch_radius"]))[:4]  # the 4 eye corners
    positions, confidence, vids, rms_all, expected = {}, {}, {}, [], []
    for i, nm in enumerate(LANDMARK_NAMES):
        local = scale * (model.graph_points[i] + model.offset_mean[i])
        expected.append(local @ r.T + t)
        rp, tp, prms, _ = trimmed_icp(scale * patches[i], feat.tree, r, t, iters=20, keep=0.9,
                                      normals=feat.normals)
        x = local @ rp.T + tp
        m2 = float(mahalanobis2((x - expected[-1]) @ r / scale, np.zeros(3), model.offset_cov[i]))
        if m2 > RUNAWAY_M2:
            # the patch slid off (a strong expression, a hole): the global prediction is safer
            flags.append(f"patch_slid:{nm}")
            x = expected[-1]
        _, v = feat.tree.query(x[None])
        v = int(np.asarray(v).ravel()[0])
        vids[nm], positions[nm] = v, feat.vertices[v].copy()
        confidence[nm] = float(np.clip(min(1.0, 2.0 * float(chdtrc(3, m2))) * min(1.0, (2.0 / max(prms, 1e-9)) ** 2), 0, 1))
        rms_all.append(prms)
    return positions, confidence, vids, np.array(expected), dict(scale=scale, patch_rms=rms_all, flags=flags)


def _paper_pose(mesh, feat, model, opts, timer, name, flags):
    """Paper §3.4-3.6 start: umbilics, FPPCA labels, nose-first search, graph alignment in both
    5/6 labellings, then the template ICP from those alignments (:func:`_pose`). Returns
    (R, t, trimmed rms mm, debug dict); appends reasons for doubt to ``flags``."""
    with timer("umbilics"):
        from ..curvature import umbilics

        umb = np.asarray(umbilics(mesh.vertices, mesh.faces), dtype=np.int64)
    if len(umb) == 0:
        raise LandmarkError(f"{name}: no umbilics found: not a face surface (too small or flat?)")
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
        for k in labelled[: max(1, int(opts["n_starts"]))]:
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
    return r, t, rms, dict(nose_hypotheses=list(hyps), d_f=d_f, n_umbilics=len(umb), starts=starts)


def _template_tip_plane_normal(model, radius: float) -> np.ndarray:
    """Unit normal (3,) of the least-squares plane of the template's ICP points within
    ``radius`` mm of Pa's nose tip: the template-side twin of the scan's protrusion plane."""
    pts = model.icp_points
    near = pts[np.linalg.norm(pts - model.graph_points[NOSE_TIP], axis=1) < radius]
    if len(near) < 3:
        return model.icp_tip_normal
    _, vec = np.linalg.eigh(np.cov(near.T))
    n = vec[:, 0]
    return n if n @ model.icp_tip_normal >= 0 else -n


def _protrusion_pose(feat, model, opts, timer, name):
    """Default start: the ``n_tip_candidates`` most protruding points (:mod:`.protrusion`), each
    with a sweep of ``sweep_angles`` rotations about its plane normal, then the template ICP;
    the pose with the smallest trimmed residual wins. Returns (R, t, rms mm, debug dict)."""
    from .pose import fit_poses, normal_sweep_starts, trimmed_icp
    from .protrusion import nose_tip_candidates

    radius = float(opts["protrusion_radius"])
    with timer("starts"):
        tips = nose_tip_candidates(feat.vertices, feat.normals, k=int(opts["n_tip_candidates"]), radius=radius)
        if not tips or tips[0][1] < float(opts["min_protrusion"]):
            top = f"{tips[0][1]:.1f} mm" if tips else "none"
            raise LandmarkError(f"{name}: nothing protrudes like a nose (highest protrusion {top}, "
                                f"a nose tip stands ~10 mm out): not a face, or wrong units?")
        tpl_n = _template_tip_plane_normal(model, radius)
        starts = []
        for vid, _, n in tips:
            starts += normal_sweep_starts(model.graph_points[NOSE_TIP], tpl_n, feat.vertices[vid], n,
                                          int(opts["sweep_angles"]))
    with timer("pose"):
        poses = fit_poses(model.icp_points, feat.tree, starts, n_best=int(opts["n_poses"]), normals=feat.normals)
        # A face and its upside-down image can fit the upper face almost equally well (forehead
        # on the chin); the whole template (mouth and chin too) tells them apart: measured on
        # the 2 upside-down results of the 350 test scans, the right pose had the lowest
        # whole-template residual while its upper-face residual was 0.1-0.15 mm higher.
        full = _template_surface_points(model)
        scores = [trimmed_icp(full, feat.tree, pr, pt, iters=10, normals=feat.normals)[2] for pr, pt, _ in poses]
        r, t, rms = poses[int(np.argmin(scores))]
    return r, t, rms, dict(tip_candidates=[(v, h) for v, h, _ in tips], pose_rms=[p[2] for p in poses],
                           pose_full_rms=scores)


def _predict_once(mesh, model, opts) -> "LandmarkResult":
    """One prediction with fixed settings (see :func:`predict_landmarks`)."""
    timer = _Timer()
    name = mesh.source or "scan"
    with timer("prepare"):
        feat = ScanFeatures(mesh.vertices, mesh.faces, model.radii)
    flags = []
    if opts["start_search"] == "protrusion":
        r, t, rms, start_debug = _protrusion_pose(feat, model, opts, timer, name)
    elif opts["start_search"] == "paper":
        r, t, rms, start_debug = _paper_pose(mesh, feat, model, opts, timer, name, flags)
    else:
        raise ValueError(f"start_search must be 'protrusion' or 'paper', got {opts['start_search']!r}")
    if opts["localise"] == "patch":
        with timer("patches"):
            positions, confidence, vids, expected, loc_debug = _patch_localise(feat, model, (r, t), opts)
    elif opts["localise"] == "bp":
        try:
            best = _localise(feat, model, (r, t), opts, timer)
        except ValueError as e:
            raise LandmarkError(f"{name}: landmark search failed ({e})") from None
        positions, confidence, vids, expected, loc_debug = _bp_outputs(feat, model, best, opts)
    else:
        raise ValueError(f"localise must be 'patch' or 'bp', got {opts['localise']!r}")
    flags += loc_debug.pop("flags", [])
    ref_rms = float(model.param("mean_icp_rms") or 1.0)
    if rms > 3.0 * max(ref_rms, 0.5):
        flags.append(f"poor_face_fit:icp_rms={rms:.1f}mm (training {ref_rms:.1f}mm)")
    flags = list(dict.fromkeys(flags))
    for nm in LANDMARK_NAMES:
        if confidence[nm] < opts["low_confidence"]:
            flags.append(f"low_confidence:{nm}")
    # Geometric plausibility: the posed Pa must lie on the surface (a half face or a hole over
    # the nose leaves part of it in the air).
    d_surf, _ = feat.tree.query(expected)
    if np.max(d_surf) > 8.0:
        off = [LANDMARK_NAMES[k] for k in np.flatnonzero(np.asarray(d_surf) > 8.0)]
        flags.append(f"graph_off_surface:{','.join(off)} (half face or missing region?)")
    pred = np.array([positions[n] for n in LANDMARK_NAMES])
    tpl = model.graph_points
    span = np.linalg.norm(pred[0] - pred[3]) / max(np.linalg.norm(tpl[0] - tpl[3]), 1e-9)
    if not 0.6 < span < 1.5:
        flags.append(f"implausible_eye_span:{span:.2f}x template")
    debug = dict(start_debug, **loc_debug, pose=(r, t), icp_rms=rms)
    timings = dict(timer.t)
    timings["total"] = float(sum(timer.t.values()))
    return LandmarkResult(positions=positions, confidence=confidence, flags=flags, timings_s=timings,
                          vertex_ids=vids, debug=debug)
