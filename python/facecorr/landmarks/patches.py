"""The default localisation: the template's own surface around each landmark, fitted locally."""

from __future__ import annotations

import numpy as np
from ..chi2 import chi2_sf  # the χ² tail without scipy (scipy.special costs 0.15-0.4 s to import)

from ..names import LANDMARK_NAMES, NOSE_TIP
from .gaussian import mahalanobis2
from .pose import similarity_icp, surface_icp
from .start import _PATCH_CACHE, packaged_template


#: A patch whose displacement from the global prediction has a squared Mahalanobis distance
#: (learned offset covariance) above this (chi2, 3 dof, p = 0.001) is rejected.
#: ``scipy.special.chdtri(3, 0.001)``, written out (tests/test_chi2.py checks it).
RUNAWAY_M2 = 16.26623619623813


def _template_patches(model, radius: float) -> list:
    """Per landmark, the packaged template's vertices (P_i, 3) within ``radius`` mm of its Pa
    point (template frame, mm). Raises LandmarkError if the model's Pa is not this template's."""
    key = (model.graph_points.tobytes(), float(radius))
    if key not in _PATCH_CACHE:
        tpl = packaged_template(model)
        lm = tpl.vertices[tpl.landmark_ids]
        _PATCH_CACHE[key] = tuple(tpl.vertices[np.linalg.norm(tpl.vertices - p, axis=1) < radius] for p in lm)
    return list(_PATCH_CACHE[key])


def patch_localise(mesh, model, pose, opts):
    """Default localisation: the template's own surface around each landmark, fitted locally.

    ``pose``: (R, t) or (R, t, s), the template posed as ``x -> s R x + t`` (s = 1 if absent).

    1. the pose gains a uniform scale (:func:`.pose.similarity_icp` of the upper face);
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
    r, t, *rest = pose
    from .start import pose_points

    r, scale, t, _ = similarity_icp(pose_points(model, float(opts.similarity_points_radius)), mesh.kdtree, r, t,
                                    scale=float(rest[0]) if rest else 1.0)
    flags = [] if 0.75 < scale < 1.33 else [f"implausible_face_scale:{scale:.2f}x template"]
    scale = float(np.clip(scale, 0.75, 1.33))
    patches = _template_patches(model, float(opts.patch_radius))
    patches[NOSE_TIP] = _template_patches(model, float(opts.tip_patch_radius))[NOSE_TIP]
    patches[:4] = _template_patches(model, float(opts.eye_patch_radius))[:4]  # the 4 eye corners
    positions, confidence, vids, rms_all, expected = {}, {}, {}, [], []
    for i, nm in enumerate(LANDMARK_NAMES):
        local = scale * (model.graph_points[i] + model.offset_mean[i])
        expected.append(local @ r.T + t)
        rp, tp, prms, _ = surface_icp(scale * patches[i], mesh.surface, [(r, t)], iters=20, keep=0.9)[0]
        x = local @ rp.T + tp
        m2 = float(mahalanobis2((x - expected[-1]) @ r / scale, np.zeros(3), model.offset_cov[i]))
        if m2 > RUNAWAY_M2:
            # the patch slid off (a strong expression, a hole): the global prediction is safer
            flags.append(f"patch_slid:{nm}")
            x = expected[-1]
        _, v = mesh.kdtree.query(x[None])
        v = int(np.asarray(v).ravel()[0])
        vids[nm], positions[nm] = v, mesh.vertices[v].copy()
        confidence[nm] = float(np.clip(min(1.0, 2.0 * chi2_sf(3, m2)) * min(1.0, (2.0 / max(prms, 1e-9)) ** 2), 0, 1))
        rms_all.append(prms)
    return positions, confidence, vids, np.array(expected), dict(scale=scale, patch_rms=rms_all, flags=flags)

