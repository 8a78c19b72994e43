"""The whole method on one scan: landmarks -> affine -> expression -> shape (paper §3-4).

:func:`correspond` is the Python entry point; :class:`Result` carries the registered template
(template vertex order, the scan's frame) and everything the CLI writes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .mesh import Mesh
from .names import LANDMARK_NAMES


@dataclass
class Result:
    """A registered scan.

    Attributes
    ----------
    vertices : (N, 3) float64, the template deformed onto the scan, mm, the scan's frame.
    faces : (M, 3) int64, the template's triangles (the same for every scan).
    landmarks : dict name -> (3,) mm, the landmarks the registration was guided by.
    landmarks_registered : dict name -> (3,) mm, the 8 landmarks read off the registered template.
    confidence : dict name -> float in [0, 1] (1 for landmarks given by the user).
    expression_weights : dict blendshape name -> fitted weight in [0, 1].
    mhd : float, modified Hausdorff distance template -> scan, mm.
    timings_s : dict stage -> seconds.
    flags : list of str, warnings (low-confidence landmarks, ...).
    to_mm, units : the scan's units (results are written back in them).
    """

    vertices: np.ndarray
    faces: np.ndarray
    landmarks: dict
    landmarks_registered: dict
    confidence: dict
    expression_weights: dict
    mhd: float
    timings_s: dict
    flags: list = field(default_factory=list)
    to_mm: float = 1.0
    units: str = "mm"

    def to_json(self) -> dict:
        """The JSON contract of ``facecorr register --json`` (coordinates and MHD in the scan's units)."""
        s = 1.0 / self.to_mm
        return {
            "units": self.units,
            "landmarks": {k: (np.asarray(v) * s).tolist() for k, v in self.landmarks.items()},
            "landmarks_registered": {k: (np.asarray(v) * s).tolist() for k, v in self.landmarks_registered.items()},
            "confidence": {k: float(v) for k, v in self.confidence.items()},
            "expression_weights": {k: float(v) for k, v in self.expression_weights.items()},
            "mhd": float(self.mhd) * s,
            "timings_s": {k: round(float(v), 4) for k, v in self.timings_s.items()},
            "flags": list(self.flags),
        }

    def save(self, mesh_path, json_path=None) -> None:
        """Write the registered template (scan's units) and optionally the JSON, each atomically."""
        from .fileio import atomic_path, write_json
        from .io import save_mesh

        with atomic_path(mesh_path) as tmp:
            save_mesh(tmp, (self.vertices / self.to_mm, self.faces))
        if json_path is not None:
            write_json(json_path, self.to_json())


#: Shape-fit landmark weight when the landmarks were predicted (see :func:`correspond`).
PREDICTED_LANDMARK_WEIGHT = 0.0


def correspond(mesh: Mesh, *, landmarks: dict | None = None, model=None, template=None) -> Result:
    """Register the template onto ``mesh`` fully automatically.

    Parameters
    ----------
    mesh : Mesh in mm (see :func:`facecorr.load_mesh`), any pose, cropped or raw.
    landmarks : optional dict name -> (3,) mm of the 8 landmarks (facecorr.names.LANDMARK_NAMES);
        when given, landmark prediction is skipped.
    model : a trained landmark model (default: the packaged one).
    template : a Template (default: the packaged one).

    Returns
    -------
    Result
    """
    from .registration import register
    from .template import load_template

    template = template or load_template()
    timings = {}
    flags = []
    t0 = time.perf_counter()
    if landmarks is None:
        from .landmarks import predict_landmarks

        pred = predict_landmarks(mesh, model=model)
        positions = {k: np.asarray(v, float) for k, v in pred.positions.items()}
        confidence = dict(pred.confidence)
        flags += list(pred.flags)
        timings.update({f"landmarks.{k}": v for k, v in pred.timings_s.items()})
    else:
        missing = [n for n in LANDMARK_NAMES if n not in landmarks]
        if missing:
            from .errors import LandmarkError

            raise LandmarkError(f"landmarks given without {', '.join(missing)}")
        positions = {n: np.asarray(landmarks[n], float) for n in LANDMARK_NAMES}
        confidence = {n: 1.0 for n in LANDMARK_NAMES}
    timings["landmarks"] = time.perf_counter() - t0
    # The shape fit's landmark term pins the template's landmarks to the given points: right for
    # landmarks a user supplies, harmful for predicted ones (2-3 mm off). Measured on the first 21
    # bu3dfe test scans with predicted landmarks: weight 10 -> 0 takes eyes 1.47/1.55 -> 1.26/1.18
    # mm and nose 1.40 -> 1.18 mm, brows/mouth/dense unchanged (BENCHMARKS.md, "Registration").
    options = {} if landmarks is not None else {"shape_landmark_weight": PREDICTED_LANDMARK_WEIGHT}
    reg = register(mesh, positions, template=template, **options)
    doubts = reg.implausible()
    if doubts and landmarks is None and "retried_wider_search" not in flags:
        # Landmarks in a wrong pose show as a fit the model cannot explain: predict again with
        # the wider start search and keep the better-explained fit (bu3dfe test split: the one
        # scan of 350 with eye corners 30-50 mm off; the retry puts all 8 within 1-7 mm).
        from .landmarks import predict_landmarks
        from .landmarks.predict import RETRY_OVERRIDES

        t1 = time.perf_counter()
        pred2 = predict_landmarks(mesh, model=model, **RETRY_OVERRIDES)
        pos2 = {k: np.asarray(v, float) for k, v in pred2.positions.items()}
        reg2 = register(mesh, pos2, template=template, **options)
        timings["refit"] = time.perf_counter() - t1
        if reg2.details.get("fit_rms_mm", np.inf) < reg.details.get("fit_rms_mm", np.inf):
            reg, positions, confidence = reg2, pos2, dict(pred2.confidence)
            flags = list(pred2.flags)  # the first prediction's doubts no longer apply
            doubts = reg.implausible()
        flags.append("refit_wider_search_after_implausible_fit")
    flags += [f"implausible_fit:{d}" for d in doubts]
    timings.update({f"registration.{k}": v for k, v in reg.timings_s.items()})
    timings["total"] = time.perf_counter() - t0
    return Result(
        vertices=reg.vertices,
        faces=np.asarray(template.faces, dtype=np.int64),
        landmarks=positions,
        landmarks_registered=dict(reg.landmarks_registered),
        confidence=confidence,
        expression_weights={str(n): float(a) for n, a in zip(template.blendshape_names, reg.alpha)},
        mhd=float(reg.mhd),
        timings_s=timings,
        flags=flags,
        to_mm=mesh.to_mm,
        units=mesh.units,
    )


def plot_registration(mesh: Mesh, result: Result, path, template=None, title=None) -> None:
    """PNG of the scan beside the registered template coloured by point-to-plane distance (mm).

    Both are drawn in the template's frame (a rigid fit of the result onto the template's rest
    pose), front view, like the paper's Fig. 11.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .fileio import atomic_path
    from .render import draw_mesh, kabsch
    from .spatial import KDTree
    from .template import load_template

    template = template or load_template()
    r, t = kabsch(result.vertices, np.asarray(template.vertices, float))
    scan_v = mesh.vertices @ r.T + t
    reg_v = result.vertices @ r.T + t
    # point-to-plane distance from each registered vertex to its nearest scan vertex's tangent plane
    dist, idx = KDTree(mesh.vertices).query(result.vertices, k=1)
    n = mesh.vertex_normals[idx]
    p2p = np.abs(np.einsum("ij,ij->i", result.vertices - mesh.vertices[idx], n))
    centre = reg_v.mean(axis=0)
    keep = np.linalg.norm(scan_v - centre, axis=1) < 1.3 * np.linalg.norm(reg_v - centre, axis=1).max()
    fkeep = keep[mesh.faces].all(axis=1)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.5))
    lm = np.array([result.landmarks[k] for k in LANDMARK_NAMES]) @ r.T + t
    draw_mesh(axes[0], scan_v, mesh.faces[fkeep], points=lm)
    axes[0].set_title("scan (red: the landmarks used)")
    sm = draw_mesh(axes[1], reg_v, result.faces, values=p2p, cmap="turbo", vmin=0.0, vmax=1.0)
    axes[1].set_title(f"registered template, MHD {result.mhd:.2f} mm")
    fig.colorbar(sm, ax=axes[1], fraction=0.04, label="point-to-plane distance to scan [mm] (clamped at 1)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
