"""The default start: a rigid pose of the template from the most protruding points.

The ``n_tip_candidates`` most protruding points (:mod:`.protrusion`; and the point furthest out
along the scan's viewing axis) each seed a sweep of rigid
starts about their plane normal; a trimmed point-to-plane ICP of the template's upper face near
the nose (:func:`pose_points`, :mod:`.pose`) refines each candidate's best (a face and its upside-down image), and the whole
template's residual, less a share of the candidate's protrusion, picks among them: on raw scans a
shoulder or a hairy scalp can fit the upper face better than an unusual face (BENCHMARKS.md,
"Out of model, second pass").
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import LandmarkError
from ..geometry.spatial import voxel_subsample
from ..names import NOSE_TIP
from .pose import fit_poses, normal_sweep_starts, surface_icp, trimmed_icp
from .protrusion import nose_tip_candidates


_PATCH_CACHE: dict = {}


def packaged_template(model):
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
        tpl = packaged_template(model)
        _PATCH_CACHE[key] = tpl.vertices[voxel_subsample(tpl.vertices, np.arange(tpl.n_vertices), spacing)]
    return _PATCH_CACHE[key]


def pose_points(model, radius: float = 0.0) -> np.ndarray:
    """(P, 3) the model's upper-face ICP points (mm) within ``radius`` mm of Pa's nose tip (0: all).

    Near the nose the face is rigid and its shape varies least between people; a forehead
    sloped unlike the template's (or hair over it) tilts a fit of the whole upper face."""
    if radius <= 0:
        return model.icp_points
    pts = model.icp_points
    near = pts[np.linalg.norm(pts - model.graph_points[NOSE_TIP], axis=1) < radius]
    return near if len(near) >= 10 else pts


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


def _pose_score(points, tree, r, t, normals, kind: str, scale: float = 1.0, iters: int = 10) -> float:
    """How well the posed template ``points`` (P, 3) fit the scan (lower is better), after ``iters``
    trimmed ICP iterations at the fixed ``scale``: ``"trimmed"`` the RMS of the closest 80 %
    (mm); ``"truncated"`` the mean of min(d, 3 mm)² over all points (mm²), which a region the
    template cannot reach (a beard, hair, clothing) caps instead of hiding it by a fixed share."""
    pts = scale * points
    r, t, rms, d = trimmed_icp(pts, tree, r, t, iters=iters, normals=normals)
    if kind == "trimmed":
        return rms
    return float(np.mean(np.minimum(np.asarray(d), TRUNCATION_MM) ** 2))


def _pose_scores(points, mesh, poses, kind: str, iters: int = 10, offsets=None, first_iters: int = 0,
                 margin: float = np.inf):
    """:func:`_pose_score` of every pose (R, t, scale) of ``poses`` on ``mesh``: the same scores,
    the ICPs in Rust on ``mesh.surface`` (:func:`.pose.surface_icp`), the poses of one template
    size in one call (in parallel). Returns (scores (P,) list, finish): ``finish()`` gives every
    pose's score after ``iters`` iterations (computed on first call, then kept).

    ``first_iters`` > 0 scores in two rounds (successive halving): every pose after
    ``first_iters`` iterations, then only the poses whose score plus ``offsets`` (P,) (what the
    caller adds to a score before ranking; None: 0) lies within ``margin`` of the best go on,
    resumed where they stopped (bitwise the scores of one run of ``iters``); the others keep
    their first-round score in ``scores``, and ``finish()`` resumes them too when asked. Measured
    on 564 pose searches (490 test scans, three splits): after 3 iterations the eventual winner
    was at most 1.48 mm behind the best, so a 2.5 mm margin loses no winner while ~60 % of the
    poses stop early (BENCHMARKS.md, "Throughput, eighth pass")."""
    offsets = np.zeros(len(poses)) if offsets is None else np.asarray(offsets, dtype=np.float64)

    def score(fit):
        return fit[2] if kind == "trimmed" else float(np.mean(np.minimum(fit[3], TRUNCATION_MM) ** 2))

    def run(ks, starts, prevs, n_iter):
        fits = {}
        for s in sorted({float(poses[k][2]) for k in ks}):
            ids = [k for k in ks if float(poses[k][2]) == s]
            for k, fit in zip(ids, surface_icp(s * points, mesh.surface, [starts[k] for k in ids], iters=n_iter,
                                               prev=[prevs[k] for k in ids], return_prev=True)):
                fits[k] = fit
        return fits

    def resume(ks):
        return run(ks, {k: first[k][:2] for k in ks}, {k: first[k][4] for k in ks}, iters - first_iters)

    every = list(range(len(poses)))
    starts = {k: p[:2] for k, p in enumerate(poses)}
    if not 0 < first_iters < iters:
        fits = run(every, starts, {k: np.inf for k in every}, iters)
        out = [score(fits[k]) for k in every]
        return out, lambda: list(out)
    first = run(every, starts, {k: np.inf for k in every}, first_iters)
    out = [score(first[k]) for k in every]
    ranked = np.asarray(out) + offsets
    go_on = [k for k in every if ranked[k] <= ranked.min() + margin]
    for k, fit in resume(go_on).items():
        out[k] = score(fit)
    full = []

    def finish():
        if not full:
            rest = resume([k for k in every if k not in go_on])
            full.extend(score(rest[k]) if k in rest else out[k] for k in every)
        return list(full)

    return out, finish


class LazyPoses(Sequence):
    """A list of poses (R (3, 3), t (3,) mm, ICP rms mm, template size) computed on first use by
    ``compute()`` and translated by ``offset`` (3,) mm: the alternative poses, which only a refit
    of an implausible fit reads, and which cost the stopped pose scores' remaining iterations."""

    def __init__(self, compute, offset=None, _cache=None):
        self._compute, self._cache = compute, ([] if _cache is None else _cache)
        self._offset = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)

    def _poses(self) -> list:
        if not self._cache:
            self._cache.append(self._compute())
        return [(r, np.asarray(t) + self._offset, rms, size) for r, t, rms, size in self._cache[0]]

    def __getitem__(self, i):
        return self._poses()[i]

    def __len__(self) -> int:
        return len(self._poses())

    def __add__(self, other) -> list:
        return self._poses() + list(other)

    def __radd__(self, other) -> list:
        return list(other) + self._poses()

    def __repr__(self) -> str:
        return f"LazyPoses({self._poses() if self._cache else '<not computed>'})"

    def moved(self, offset) -> "LazyPoses":
        """The same poses translated by ``offset`` (3,) mm more (computed once for both)."""
        return LazyPoses(self._compute, self._offset + np.asarray(offset, dtype=np.float64), self._cache)


#: The truncation distance of the ``"truncated"`` pose score, mm: a skin point that matches lies
#: within ~1-2 mm (noise, expression), one on hair, a beard or the wrong part of the face beyond.
TRUNCATION_MM = 3.0


def protrusion_pose(mesh, model, opts, timer, name):
    """Default start: the ``n_tip_candidates`` most protruding points (:mod:`.protrusion`, on the
    pieces of at least ``nose_piece_fraction`` of the largest one's area, heights median-smoothed
    over ``protrusion_median_k`` neighbours; with ``axis_tip_candidate`` also the point furthest
    out along the scan's axis of least variance), each with a sweep of ``sweep_angles`` rotations about
    its plane normal at each of the template sizes ``pose_scales``, then the template ICP: each
    candidate's ``poses_per_tip`` best poses (0: the ``n_poses`` best of all candidates together);
    the pose with the best whole-template score (``pose_score``, less ``pose_height_weight`` × the
    candidate's protrusion) wins. Returns (R, t, rms mm, debug dict with ``"pose_scale"``): the
    template is posed as ``x -> pose_scale * R x + t``."""
    radius = float(opts.protrusion_radius)
    with timer("starts"):
        keep = None
        if opts.nose_piece_fraction > 0:
            areas = mesh.component_areas
            keep = np.isin(mesh.components, np.flatnonzero(areas >= float(opts.nose_piece_fraction) * areas[0]))
        tips = nose_tip_candidates(mesh.vertices, mesh.vertex_normals, k=int(opts.n_tip_candidates), radius=radius,
                                   keep=keep, median_k=int(opts.protrusion_median_k),
                                   spacing=float(opts.protrusion_spacing), extreme_axis=bool(opts.axis_tip_candidate))
        if not tips or tips[0][1] < float(opts.min_protrusion):
            top = f"{tips[0][1]:.1f} mm" if tips else "none"
            raise LandmarkError(f"{name}: nothing protrudes like a nose (highest protrusion {top}, "
                                f"a nose tip stands ~10 mm out): not a face, or wrong units?")
        tpl_n = _template_tip_plane_normal(model, radius)
        sizes = tuple(float(s) for s in opts.pose_scales)
        groups = []  # per nose-tip candidate: (its height, its starts, their template sizes)
        for vid, h, n in tips:
            st, sc = [], []
            for s in sizes:
                # the template scaled by s about its origin: the nose tip's start moves with it
                st += normal_sweep_starts(s * model.graph_points[NOSE_TIP], tpl_n, mesh.vertices[vid], n,
                                          int(opts.sweep_angles))
                sc += [s] * int(opts.sweep_angles)
            groups.append((h, st, sc))
    with timer("pose"):
        # the upper-face ICP refines every pose before the scores (40 iterations each), or only
        # the winner, the whole-template score's own ICP having moved the others from coarse
        fine = 40 if opts.refine_all_poses else 0
        coarse = None
        if opts.coarse_scan_spacing > 0:
            from ..geometry.spatial import KDTree

            sub = voxel_subsample(mesh.vertices, np.arange(mesh.n_vertices), float(opts.coarse_scan_spacing))
            coarse = (KDTree(mesh.vertices[sub]), mesh.vertex_normals[sub])
        if opts.poses_per_tip > 0:
            # each candidate keeps its own best poses: on a raw scan the template's upper face can
            # fit a shoulder or a hairy scalp better, in the coarse ranking, than an unusual face
            poses = [p + (h,) for h, st, sc in groups
                     for p in _fit_poses_sized(mesh, model, st, sc, int(opts.poses_per_tip), fine, coarse,
                                               int(opts.pose_coarse_iters), opts.pose_points_radius)]
        else:
            poses = [p + (np.nan,) for p in _fit_poses_sized(mesh, model, [x for g in groups for x in g[1]],
                                                             [x for g in groups for x in g[2]], int(opts.n_poses),
                                                             fine, coarse, int(opts.pose_coarse_iters),
                                                             opts.pose_points_radius)]
        # A face and its upside-down image can fit the upper face almost equally well (forehead
        # on the chin); the whole template (mouth and chin too) tells them apart: measured on
        # the 2 upside-down results of the 350 test scans, the right pose had the lowest
        # whole-template residual while its upper-face residual was 0.1-0.15 mm higher.
        full = _template_surface_points(model, float(opts.pose_score_spacing))
        # a nose tip stands out of its ball: a pose seeded at a higher protrusion is likelier
        bonus = (float(opts.pose_height_weight) * np.array([p[4] for p in poses])
                 if opts.pose_height_weight > 0 and opts.poses_per_tip > 0 else np.zeros(len(poses)))
        scores, finish = _pose_scores(full, mesh, [(pr, pt, s) for pr, pt, _, s, _ in poses], opts.pose_score,
                                      int(opts.pose_score_iters), offsets=-bonus,
                                      first_iters=int(opts.pose_score_first_iters),
                                      margin=float(opts.pose_score_margin))
        scores = [sc - b for sc, b in zip(scores, bonus)]
        best = int(np.argsort(scores)[0])

        def posed(i):
            r, t, rms, s, _ = poses[i]
            if not fine:
                r, t, rms, _ = surface_icp(s * pose_points(model, opts.pose_points_radius), mesh.surface, [(r, t)],
                                           iters=40)[0]
            return r, t, rms, s

        def alternatives():
            # every pose's full score (the stopped ones resumed): the order of one-round scores
            final = [sc - b for sc, b in zip(finish(), bonus)]
            order = [best] + [int(i) for i in np.argsort(final) if int(i) != best]
            return [posed(i) for i in _distinct_poses(model, poses, order, int(opts.n_alternative_poses),
                                                      float(opts.alternative_pose_distance))]

        r, t, rms, s = posed(best)
    return r, t, rms, dict(tip_candidates=[(v, h) for v, h, _ in tips], pose_rms=[p[2] for p in poses],
                           pose_full_rms=scores, pose_scale=s, alternative_poses=LazyPoses(alternatives))


def _distinct_poses(model, poses, order, n: int, distance: float) -> list:
    """Indices of the ``n`` best poses after the winner ``order[0]`` (``order``: best first) whose
    posed landmark graph lies ≥ ``distance`` mm (mean over the 8 points) from the winner's and
    from every one taken before: other readings of the scan, not the same pose again."""
    graph = [s * model.graph_points @ r.T + t for r, t, _, s, _ in poses]
    taken, out = [order[0]], []
    for i in order[1:]:
        if len(out) >= n:
            break
        if all(np.linalg.norm(graph[i] - graph[j], axis=1).mean() >= distance for j in taken):
            taken.append(i)
            out.append(i)
    return out


def _fit_poses_sized(mesh, model, starts, scales, n_best, fine_iters=40, coarse_scan=None, coarse_iters=8,
                     points_radius=0.0):
    """:func:`.pose.fit_poses` of the template's upper face (:func:`pose_points` within
    ``points_radius`` mm of the nose tip) from ``starts`` at the template sizes ``scales`` (one per
    start), ``fine_iters`` refinement iterations, the coarse stage on ``coarse_scan`` (a subsampled
    scan's tree and normals; None: the scan): [(R, t, rms, size), ...]."""
    points = pose_points(model, points_radius)
    if all(s == 1.0 for s in scales):  # the rigid search (bitwise as before)
        return [(pr, pt, rms, 1.0) for pr, pt, rms in
                fit_poses(points, mesh.kdtree, starts, n_best=n_best, normals=mesh.vertex_normals,
                          fine_iters=fine_iters, coarse_scan=coarse_scan, coarse_iters=coarse_iters,
                          surface=mesh.surface)]
    return fit_poses(points, mesh.kdtree, starts, n_best=n_best, normals=mesh.vertex_normals,
                     scales=np.array(scales), fine_iters=fine_iters, coarse_scan=coarse_scan, coarse_iters=coarse_iters,
                     surface=mesh.surface)
