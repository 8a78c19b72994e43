"""Landmark prediction on an untouched scan (paper §3.2-3.6, and the faster, more accurate default).

Two start searches (``start_search``) and two localisations (``localise``) combine:

* default, ``protrusion`` + ``patch`` (~1 s per 35k-vertex scan): the most protruding points
  (:mod:`.protrusion`) seed a rigid ICP of the template's upper face (sweep about the protrusion
  plane normal); the whole-template residual picks among the best poses; a uniform scale is
  fitted; each landmark is carried by a local ICP of the template's own surface around it.
* the paper, ``paper`` + ``bp`` (~8 s): umbilics, FPPCA labels, nose-first search, graph
  alignment with the flip test, then FP node + canonical-form edge potentials and loopy BP.
  Measured side by side on the bu3dfe test split in BENCHMARKS.md ("Landmarks").

Modules: :mod:`.start` (the protrusion start), :mod:`.patches` (the patch localisation),
:mod:`.paper` (the paper's start, :mod:`.paper.search`, and its BP localisation,
:mod:`.paper.localise`). Every setting is a field of :class:`PredictOptions`.

Stages (their wall times are returned in ``LandmarkResult.timings_s``):

``prepare``     the scan's KD-tree and vertex normals (cached on the Mesh for every later stage).
``starts``      (protrusion) nose-tip candidates and the rotation sweep about each.
``patches``     (patch) similarity refinement and the per-landmark template-patch fits.
``features``    (paper) the geodesic solver and FP machinery over the scan (compiled core).
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
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import LandmarkError
from ..names import LANDMARK_NAMES
from ..options import resolve


#: Flags that mean "the whole graph is probably misplaced" (31 of 34 such failures flagged, no
#: false alarm on 36 good scans, BENCHMARKS.md).
FAILURE_FLAGS = ("graph_off_surface", "poor_face_fit")


@dataclass(frozen=True)
class PredictOptions:
    """Prediction settings not stored in the model (they do not depend on training); lengths in mm.

    The ``retry_*`` fields are the wider start search used when a first prediction fails its own
    checks (graph off the surface, poor face fit): more protrusion candidates and a finer sweep
    (default start; 19 of the 350 bu3dfe test scans retried, ~1 s each) or more umbilic starts
    (paper start; 6 of 10 such failures corrected, ~10 s per retry). :meth:`wider` applies them.
    """

    start_search: str = "protrusion"  # "protrusion" (default) or "paper" (umbilics + FPPCA + nose search)
    n_tip_candidates: int = 6         # protrusion maxima tried as nose tips
    protrusion_radius: float = 25.0   # scale of the protrusion measure
    min_protrusion: float = 4.0       # refuse a scan whose highest protrusion is lower (no nose)
    # Nose-tip candidates come from the pieces of at least this share of the largest piece's area
    # (0: every piece): glasses frames and specks float apart from the face (protrusion.py).
    nose_piece_fraction: float = 0.2
    protrusion_spacing: float = 3.0   # the scan voxel-subsampled at this spacing for the protrusion, mm
    protrusion_median_k: int = 13     # heights smoothed by the median of this many neighbours (hair spikes)
    # + the point furthest out along the scan's axis of least variance as one more nose-tip
    # candidate (protrusion.nose_tip_candidates' ``extreme_axis``): glasses and small faces can
    # hide the tip from the ball measure; on ood_holdout 3 scans better, none worse, gross
    # failures 8 -> 7 (BENCHMARKS.md, "Out of model, eighth pass").
    axis_tip_candidate: bool = True
    n_poses: int = 5                  # distinct coarse poses refined and scored by the whole template
    pose_scales: tuple = (1.0,)       # template sizes the pose search starts from (faces differ by ±20 %)
    pose_score: str = "trimmed"       # whole-template score of a pose: "trimmed" RMS or "truncated" (start.py)
    poses_per_tip: int = 2            # >0: each nose-tip candidate's own best poses (0: the n_poses best overall)
    pose_height_weight: float = 0.2   # with poses_per_tip: score minus this x the candidate's protrusion (mm/mm)
    refine_all_poses: bool = True     # the upper-face ICP refines every pose before the scores (False: the winner)
    pose_coarse_iters: int = 8        # ICP iterations of the coarse ranking of the sweep starts
    pose_score_iters: int = 10        # ICP iterations of the whole-template score from each pose
    # The score in two rounds (start._pose_scores): every pose after this many iterations, then only
    # those within ``pose_score_margin`` mm of the best go on to ``pose_score_iters`` (0: all go on).
    pose_score_first_iters: int = 3
    pose_score_margin: float = 2.5
    pose_score_spacing: float = 4.0   # the whole-template score's points: the template subsampled at this spacing, mm
    # >0: the pose search fits only the upper-face points within this many mm of the nose tip
    # (start.pose_points: 380 of 788); 0: all of them. A forehead sloped unlike the template's, or
    # hair over it, tilted the whole upper face's fit by 20 mm on some faces; the nose, eyes and
    # cheeks vary less. The wider search (``retry_pose_points_radius``) fits all of them: another
    # reading when the first fails. In model equal regions, 12 % less time; out of model fewer
    # gross failures (BENCHMARKS.md, "Out of model, fifth pass"). ``similarity_points_radius``:
    # the same for the patch localisation's similarity refinement (0: all; 55 measured worse).
    pose_points_radius: float = 55.0
    similarity_points_radius: float = 0.0
    coarse_scan_spacing: float = 0.0  # >0: the coarse pose ranking on the scan subsampled at this spacing, mm (0: all)
    # The next best poses that read the scan differently (posed landmark graph ≥ this many mm
    # apart, mean of the 8), kept as debug["alternative_poses"] [(R, t, icp rms, size)] (computed
    # when first read, start.LazyPoses): the
    # pipeline registers from them when its fit is implausible (pipeline/correspond.py).
    n_alternative_poses: int = 2
    alternative_pose_distance: float = 10.0
    localise: str = "patch"           # "patch" (default: local template fits) or "bp" (paper: FP + BP)
    patch_radius: float = 20.0        # template patch around the subalare and the subnasal
    tip_patch_radius: float = 25.0    # the nose tip's (its 20 mm patch slides along the ridge)
    eye_patch_radius: float = 25.0    # the eye corners' (BENCHMARKS.md, "Landmarks")
    circle_spacing: float = 3.0       # subsampling of the geodesic search circles
    candidate_spacing: float = 1.5    # finest subsampling of the coarse BP search regions
    refine_spacing: float = 1.0       # candidates of the fine BP pass
    n_starts: int = 3                 # nose-tip (and subnasal) start umbilics
    # The paper start skips umbilics nearer the scan's outer border than the largest FP radius
    # (their descriptors' disks are cut off there; paper/search.py); False: every umbilic.
    fp_border_check: bool = True
    # The paper start's choice among its ICP poses: "template" (the whole template's residual, as
    # the default start: tells a face from its upside-down image) or "fp" (the posed landmarks'
    # FP likelihood, the earlier choice; flipped 11 of 350 test scans).
    paper_pose_score: str = "template"
    n_tips: int = 2                   # nose-tip choices per start
    # paper start: distinct nose tips (of the nose hypotheses, in order) with a rotation sweep about
    # their normal (2 before 2026-12-06: the right tip was often the 3rd-8th; with the per-tip
    # poses the pose stage went from 0.3 to 1.1 s a scan, BENCHMARKS.md)
    sweep_tips: int = 12
    sweep_angles: int = 12            # rotations per sweep
    confidence_radius: float = 4.0
    low_confidence: float = 0.3       # flag below this
    bp_iterations: int = 60
    retry: bool = True                # redo a self-flagged failure with the wider search below
    retry_n_starts: int = 8
    retry_sweep_tips: int = 24
    retry_n_tips: int = 3
    retry_n_tip_candidates: int = 10
    retry_sweep_angles: int = 16
    retry_pose_points_radius: float | None = 0.0  # the wider search's; None: as ``pose_points_radius``

    def __post_init__(self):
        if self.start_search not in ("protrusion", "paper"):
            raise ValueError(f"start_search must be 'protrusion' or 'paper', got {self.start_search!r}")
        if self.paper_pose_score not in ("template", "fp"):
            raise ValueError(f"paper_pose_score must be 'template' or 'fp', got {self.paper_pose_score!r}")
        if self.pose_score not in ("trimmed", "truncated"):
            raise ValueError(f"pose_score must be 'trimmed' or 'truncated', got {self.pose_score!r}")
        if int(self.pose_score_first_iters) < 0 or not float(self.pose_score_margin) >= 0:
            raise ValueError(f"pose_score_first_iters and pose_score_margin must be >= 0, got "
                             f"{self.pose_score_first_iters!r} and {self.pose_score_margin!r}")
        if not self.pose_scales or any(not 0.5 <= float(s) <= 2.0 for s in self.pose_scales):
            raise ValueError(f"pose_scales must be template sizes in [0.5, 2], got {self.pose_scales!r}")
        if self.localise not in ("patch", "bp"):
            raise ValueError(f"localise must be 'patch' or 'bp', got {self.localise!r}")

    def wider(self) -> "PredictOptions":
        """These options with the wider start search of the ``retry_*`` fields."""
        radius = self.pose_points_radius if self.retry_pose_points_radius is None else self.retry_pose_points_radius
        return replace(self, n_starts=self.retry_n_starts, sweep_tips=self.retry_sweep_tips, n_tips=self.retry_n_tips,
                       n_tip_candidates=self.retry_n_tip_candidates, sweep_angles=self.retry_sweep_angles,
                       pose_points_radius=float(radius))


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

    def moved(self, offset) -> "LandmarkResult":
        """This result with the positions (and the debug pose) translated by ``offset`` (3,) mm."""
        offset = np.asarray(offset, dtype=np.float64)
        if not offset.any():
            return self
        debug = dict(self.debug)
        if "pose" in debug:
            r, t = debug["pose"]
            debug["pose"] = (r, np.asarray(t) + offset)
        if "alternative_poses" in debug:
            alt = debug["alternative_poses"]  # a start.LazyPoses: moved without computing it
            debug["alternative_poses"] = (alt.moved(offset) if hasattr(alt, "moved") else
                                          [(r, np.asarray(t) + offset, rms, size) for r, t, rms, size in alt])
        return replace(self, positions={k: np.asarray(v) + offset for k, v in self.positions.items()}, debug=debug)


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


def predict_landmarks(mesh, model=None, options: PredictOptions | None = None, start_pose=None,
                      **overrides) -> "LandmarkResult":
    """Predict the 8 landmarks of a face scan.

    Parameters
    ----------
    mesh : facecorr.Mesh (mm, any pose, cropped or raw); its KD-tree and normals are built once
        and cached on it for the registration.
    model : LandmarkModel, a path, or None for the packaged default.
    options : PredictOptions (default ``PredictOptions()``).
    start_pose : None, or a pose (R (3, 3), t (3,) mm, icp rms mm, template size) in the scan's
        frame, e.g. one of another prediction's ``debug["alternative_poses"]``: the landmarks are
        localised from it, without the start search or a retry.
    **overrides : fields of :class:`PredictOptions` to change, e.g. ``start_search="paper"``.

    Returns
    -------
    LandmarkResult (positions in mm, scan frame).

    Raises
    ------
    LandmarkError : no face-like structure to start from (no umbilics, no nose-tip candidate).
    """
    from .model import LandmarkModel, load_model

    opts = resolve(options, PredictOptions, overrides, "predict_landmarks")
    if not isinstance(model, LandmarkModel):
        model = load_model(model)
    work, offset = mesh.centred_outward()
    if start_pose is not None:
        r, t, rms, size = start_pose
        return _predict_once(work, model, opts, (r, np.asarray(t, float) - offset, rms, size)).moved(offset)
    best = first = _predict_once(work, model, opts)
    if opts.retry and _failed(first):
        second = _predict_once(work, model, opts.wider())
        best = second if not _failed(second) else first
        best.flags = list(dict.fromkeys(best.flags + ["retried_wider_search"]))
        best.timings_s = {k: first.timings_s.get(k, 0.0) + second.timings_s.get(k, 0.0)
                          for k in set(first.timings_s) | set(second.timings_s)}
    return best.moved(offset)


def _predict_once(mesh, model, opts: PredictOptions, start_pose=None) -> "LandmarkResult":
    """One prediction with fixed settings (see :func:`predict_landmarks`), from ``start_pose``
    (R, t, rms, size) if given."""
    timer = _Timer()
    name = mesh.source or "scan"
    with timer("prepare"):
        tree, _ = mesh.kdtree, mesh.vertex_normals
    feat = None
    if opts.start_search == "paper" or opts.localise == "bp":
        from .paper.features import ScanFeatures

        with timer("features"):
            feat = ScanFeatures(mesh, model.radii)
    flags = []
    if start_pose is not None:
        r, t, rms, size = start_pose
        start_debug = dict(pose_scale=float(size))
    elif opts.start_search == "protrusion":
        from .start import protrusion_pose

        r, t, rms, start_debug = protrusion_pose(mesh, model, opts, timer, name)
    else:
        from .paper.search import paper_pose

        r, t, rms, start_debug = paper_pose(mesh, feat, model, opts, timer, name, flags)
    if opts.localise == "patch":
        from .patches import patch_localise

        with timer("patches"):
            positions, confidence, vids, expected, loc_debug = patch_localise(
                mesh, model, (r, t, float(start_debug.get("pose_scale", 1.0))), opts)
    else:
        from .paper.localise import bp_localise, bp_outputs

        try:
            best = bp_localise(feat, model, (r, t), opts, timer)
        except ValueError as e:
            raise LandmarkError(f"{name}: landmark search failed ({e})") from None
        positions, confidence, vids, expected, loc_debug = bp_outputs(feat, model, best, opts)
    flags += loc_debug.pop("flags", [])
    ref_rms = float(model.param("mean_icp_rms") or 1.0)
    if rms > 3.0 * max(ref_rms, 0.5):
        flags.append(f"poor_face_fit:icp_rms={rms:.1f}mm (training {ref_rms:.1f}mm)")
    flags = list(dict.fromkeys(flags))
    for nm in LANDMARK_NAMES:
        if confidence[nm] < opts.low_confidence:
            flags.append(f"low_confidence:{nm}")
    # Geometric plausibility: the posed Pa must lie on the surface (a half face or a hole over
    # the nose leaves part of it in the air).
    d_surf, _ = tree.query(expected)
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

