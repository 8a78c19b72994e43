"""Training the landmark model from a synthetic database (paper §3.1, §3.4).

For every training scan (``split == "train"``; Tn = neutral scans only, Te = all of them):

1. the ground-truth landmarks are snapped to their nearest scan vertices (FP is a per-vertex
   descriptor);
2. FP descriptors at those vertices (radii :data:`DEFAULT_RADII` mm) -> node samples;
3. the canonical form (FMM geodesics + SMACOF on ``mds_samples`` farthest-point samples of the
   ``mds_region_mm`` geodesic disk around the subnasal, the same code prediction runs) gives the
   landmarks' canonical positions; these are brought into the template frame by the inverse of
   the rigid pose of step 4 (prediction uses the same ICP pose, so both see the same
   normalisation) -> edge samples
   ``x_j - x_i`` over the landmark-graph edges (``facecorr.template`` GRAPH_EDGES);
4. the rigid pose of the template's upper face (trimmed ICP, :mod:`.pose`) and the offsets of
   the true landmarks from the posed Pa points -> position prior and search radii.

Then: Gaussian ML node and edge potentials (:mod:`.gaussian`), the FPPCA classifier
(:mod:`.classify`, D = 3, M = 1.5), the Gaussian position prior and the search radii
``clip(2 * q95(offset spread) + 2 mm, 5, 25)`` per landmark.

FP radii: 8 radii from 5 to 40 mm (every 5 mm). The paper does not give its radii; 5 mm
resolves the eye corners and alae, 40 mm (about the nose length) separates the nose tip from
cheeks and chin; beyond that the cropped face's boundary truncates the disks.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..errors import FacecorrError
from ..names import LANDMARK_NAMES
from ..threads import process_map
from ..geometry.transforms import kabsch
from .paper.classify import fit_classifier
from .gaussian import fit_gaussian
from .model import DEFAULT_PARAMS, LandmarkModel

DEFAULT_RADII = np.arange(5.0, 40.0 + 1e-9, 5.0)


class TrainingError(FacecorrError, ValueError):
    """The database cannot train a model (no scans, unreadable files)."""


def template_pose_points(spacing: float = 5.0, radius: float = 85.0):
    """ICP points (P, 3) of the template's upper face within ``radius`` mm of the nose tip,
    voxel-subsampled to ``spacing`` mm, and the unit normal (3,) at the template nose tip."""
    from ..geometry.mesh import Mesh
    from ..template import REGION_NAMES, load_template
    from ..geometry.spatial import voxel_subsample

    tpl = load_template()
    v = np.asarray(tpl.vertices, dtype=np.float64)
    tip = v[int(tpl.landmark_ids[6])]
    upper = np.flatnonzero((np.asarray(tpl.regions) == REGION_NAMES.index("upper"))
                           & (np.linalg.norm(v - tip, axis=1) < radius))
    pts = v[voxel_subsample(v, upper, spacing)]
    return pts, tip_normal(Mesh(v, tpl.faces), int(tpl.landmark_ids[6]))


def tip_normal(mesh, tip: int, radius: float = 8.0) -> np.ndarray:
    """Area-weighted mean vertex normal within ``radius`` mm of vertex ``tip`` (unit)."""
    near = np.linalg.norm(mesh.vertices - mesh.vertices[tip], axis=1) < radius
    n = (mesh.vertex_normals[near] * mesh.vertex_areas[near, None]).sum(0)
    return n / max(np.linalg.norm(n), 1e-12)


def scan_training_sample(scan_path, landmarks_mm: np.ndarray, graph_points: np.ndarray, edges: np.ndarray,
                         icp_points: np.ndarray, radii=DEFAULT_RADII, params=None) -> dict:
    """Features of one training scan.

    Parameters
    ----------
    scan_path : mesh file (loaded with facecorr.io.load_mesh, mm).
    landmarks_mm : (8, 3) ground truth in LANDMARK_NAMES order, scan frame, mm.
    graph_points : (8, 3) Pa; edges : (E, 2); icp_points : (P, 3) template upper-face points.

    The pose is what prediction converges to: trimmed ICP of the template's upper face, started
    from the Kabsch fit of Pa to the true landmarks.

    Returns dict with fp (8, S), rel (E, 3), offset (8, 3), nose_d (4, 4), snap (8,) mm, ...
    """
    from ..io import load_mesh
    from .paper.features import ScanFeatures
    from .pose import trimmed_icp

    t0 = time.perf_counter()
    p = dict(DEFAULT_PARAMS, **(params or {}))
    mesh = load_mesh(scan_path, units="mm")
    feat = ScanFeatures(mesh, radii)
    lms = np.asarray(landmarks_mm, dtype=np.float64)
    snap_d, vid = feat.tree.query(lms)
    vid = np.asarray(vid, dtype=np.int64)
    fp = feat.fingerprint(vid)
    cf = feat.canonical_form(vid, int(vid[7]), float(p["mds_region_mm"]), int(p["mds_samples"]))
    r0, t0_ = kabsch(graph_points, lms)
    r, t, rms, _ = trimmed_icp(icp_points, feat.tree, r0, t0_, iters=40, normals=feat.normals)
    canon = (cf.positions - t) @ r  # template frame
    rel = canon[edges[:, 1]] - canon[edges[:, 0]]
    offset = (lms - t) @ r - graph_points
    nose = lms[4:8]
    nose_d = np.linalg.norm(nose[:, None] - nose[None], axis=-1)
    return dict(fp=fp, rel=rel, offset=offset, icp_rms=rms, snap=np.asarray(snap_d),
                seconds=time.perf_counter() - t0, rel_stress=cf.rel_stress, nose_d=nose_d)


def nose_pair_stats(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std (4, 4) of nose-point distances d (n, 4, 4) (right/left subalare, tip,
    subnasal), pooling each right-side pair with its left-side mirror; std floored at 1 mm."""
    d = np.asarray(d, dtype=np.float64)
    mirror = d[:, [1, 0, 2, 3]][:, :, [1, 0, 2, 3]]
    pooled = np.concatenate([d, mirror])
    return pooled.mean(axis=0), np.maximum(pooled.std(axis=0), 1.0)


def _records(db_dir, neutral_only: bool):
    from ..synth import load_index

    try:
        recs = load_index(db_dir)
    except FacecorrError:
        raise
    except (OSError, ValueError, KeyError) as e:
        raise TrainingError(f"{db_dir}: cannot read the database index ({type(e).__name__}: {e})") from None
    recs = [r for r in recs if r.get("split") == "train"]
    if neutral_only:
        recs = [r for r in recs if r.get("expression") == "NE"]
    if not recs:
        raise TrainingError(f"{db_dir}: no training scans{' (neutral only)' if neutral_only else ''}")
    return recs


def _gt_landmarks(gt_path) -> np.ndarray:
    data = json.loads(Path(gt_path).read_text())
    return np.array([data["landmarks"][n] for n in LANDMARK_NAMES], dtype=np.float64)


def _work(args):
    rec, pa, edges, icp_points, radii, params = args
    try:
        return scan_training_sample(rec["scan"], _gt_landmarks(rec["gt"]), pa, edges, icp_points, radii, params)
    except (FacecorrError, ValueError, OSError) as e:
        return {"error": f"{rec['scan']}: {type(e).__name__}: {e}"}


def train(db_dir, out_path, neutral_only: bool = False, workers: int = 2, radii=DEFAULT_RADII,
          params: dict | None = None, progress: bool = True) -> LandmarkModel:
    """Train a model on the database's training split and save it to ``out_path``.

    Parameters
    ----------
    db_dir : synthetic database folder (index.json).
    out_path : .npz to write (atomically).
    neutral_only : Tn (neutral scans only) instead of Te (all expressions).
    workers : process pool size (1 = in process).
    """
    from ..template import load_template

    recs = _records(db_dir, neutral_only)
    tpl = load_template()
    pa = np.asarray(tpl.graph_points, dtype=np.float64)
    edges = np.asarray(tpl.graph_edges, dtype=np.int64)
    p = dict(DEFAULT_PARAMS, **(params or {}))
    icp_points, icp_normal = template_pose_points()
    jobs = [(r, pa, edges, icp_points, np.asarray(radii, float), p) for r in recs]
    results = process_map(_work, jobs, workers=workers, desc="train", progress=progress)
    errors = [r["error"] for r in results if "error" in r]
    ok = [r for r in results if "error" not in r]
    if len(ok) < 3:
        raise TrainingError(f"only {len(ok)} usable training scans ({len(errors)} failed; first: "
                            f"{errors[0] if errors else '-'})")
    fp = np.stack([r["fp"] for r in ok])        # (n, 8, S)
    rel = np.stack([r["rel"] for r in ok])      # (n, E, 3)
    offs = np.stack([r["offset"] for r in ok])  # (n, 8, 3)
    n, L, S = fp.shape
    clf = fit_classifier(fp.reshape(-1, S), np.tile(np.arange(L), n), L)
    node = [fit_gaussian(fp[:, i], ridge=float(p["node_ridge"])) for i in range(L)]
    # Edge covariances get a 1 mm^2 floor: canonical positions are only as good as the vertex
    # spacing and the MDS fit.
    edge = [fit_gaussian(rel[:, e], ridge=1e-6, floor=1.0) for e in range(len(edges))]
    # Position prior (offset of each landmark from its Pa point after the ICP pose), with a
    # 1 mm^2 floor; search radius = 2 x the 95th percentile of the offsets' spread + 2 mm.
    off = [fit_gaussian(offs[:, i], ridge=1e-6, floor=1.0) for i in range(L)]
    spread = np.linalg.norm(offs - offs.mean(axis=0), axis=2)
    search = np.clip(2.0 * np.quantile(spread, 0.95, axis=0) + 2.0, 5.0, 25.0)
    nose_mean, nose_std = nose_pair_stats(np.stack([r["nose_d"] for r in ok]))
    p.update(trained_on=str(db_dir), n_scans=len(ok), n_failed=len(errors), neutral_only=bool(neutral_only),
             mean_snap_mm=float(np.mean([r["snap"].mean() for r in ok])),
             mean_rel_stress=float(np.mean([r["rel_stress"] for r in ok])),
             mean_icp_rms=float(np.mean([r["icp_rms"] for r in ok])))
    model = LandmarkModel(radii=np.asarray(radii, float), classifier=clf,
                          node_mean=np.array([m for m, _ in node]), node_cov=np.array([c for _, c in node]),
                          edges=edges, edge_mean=np.array([m for m, _ in edge]),
                          edge_cov=np.array([c for _, c in edge]), graph_points=pa, search_radius=search,
                          nose_pair_mean=nose_mean, nose_pair_std=nose_std, icp_points=icp_points,
                          icp_tip_normal=icp_normal, offset_mean=np.array([m for m, _ in off]),
                          offset_cov=np.array([c for _, c in off]), params=p)
    model.save(out_path)
    model.source = str(out_path)
    return model
