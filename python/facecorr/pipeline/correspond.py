"""The whole method on one scan: landmarks -> alignment -> expression -> shape (paper §3-4).

:func:`correspond` is the Python entry point; :class:`Result` carries the registered template
(template vertex order, the scan's frame) and everything the CLI writes; every setting is a field
of :class:`CorrespondOptions`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry.mesh import Mesh
from ..landmarks.predict import PredictOptions
from ..names import LANDMARK_NAMES
from ..options import resolve
from ..registration.register import RegisterOptions


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
        from ..io.atomic import atomic_path, write_json
        from ..io import save_mesh

        with atomic_path(mesh_path) as tmp:
            save_mesh(tmp, (self.vertices / self.to_mm, self.faces))
        if json_path is not None:
            write_json(json_path, self.to_json())


@dataclass(frozen=True)
class CorrespondOptions:
    """Settings of :func:`correspond`: the two stages' options and how the pipeline joins them.

    ``predicted_landmark_weight`` replaces ``register.shape.w_landmark`` when the landmarks were
    predicted: the shape fit's landmark term pins the template's landmarks to the given points,
    right for landmarks a user supplies, harmful for predicted ones (2-3 mm off; BENCHMARKS.md,
    "Where the defaults come from"). ``refit_on_implausible``: a fit the model cannot explain
    (:meth:`RegistrationResult.implausible`) is redone once from landmarks predicted with the wider
    start search (:meth:`PredictOptions.wider`), and the better-explained fit kept.
    """

    predict: PredictOptions = field(default_factory=PredictOptions)
    register: RegisterOptions = field(default_factory=RegisterOptions)
    predicted_landmark_weight: float = 0.0
    refit_on_implausible: bool = True


def correspond(mesh: Mesh, *, landmarks: dict | None = None, model=None, template=None,
               options: CorrespondOptions | None = None) -> Result:
    """Register the template onto ``mesh`` fully automatically.

    Parameters
    ----------
    mesh : Mesh in mm (see :func:`facecorr.load_mesh`), any pose, cropped or raw.
    landmarks : optional dict name -> (3,) mm of the 8 landmarks (facecorr.names.LANDMARK_NAMES);
        when given, landmark prediction is skipped.
    model : a trained landmark model (default: the packaged one).
    template : a Template (default: the packaged one).
    options : CorrespondOptions (default ``CorrespondOptions()``).

    Returns
    -------
    Result
    """
    from ..landmarks import predict_landmarks
    from ..registration import register
    from ..template import load_template

    opts = resolve(options, CorrespondOptions, {}, "correspond")
    template = template or load_template()
    timings = {}
    flags = []
    t0 = time.perf_counter()
    if landmarks is None:
        pred = predict_landmarks(mesh, model=model, options=opts.predict)
        positions = {k: np.asarray(v, float) for k, v in pred.positions.items()}
        confidence = dict(pred.confidence)
        flags += list(pred.flags)
        timings.update({f"landmarks.{k}": v for k, v in pred.timings_s.items()})
    else:
        missing = [n for n in LANDMARK_NAMES if n not in landmarks]
        if missing:
            from ..errors import LandmarkError

            raise LandmarkError(f"landmarks given without {', '.join(missing)}")
        positions = {n: np.asarray(landmarks[n], float) for n in LANDMARK_NAMES}
        confidence = {n: 1.0 for n in LANDMARK_NAMES}
    timings["landmarks"] = time.perf_counter() - t0
    reg_opts = opts.register
    if landmarks is None:
        reg_opts = replace(reg_opts, shape=replace(reg_opts.shape, w_landmark=opts.predicted_landmark_weight))
    reg = register(mesh, positions, template=template, options=reg_opts)
    doubts = reg.implausible()
    if doubts and landmarks is None and opts.refit_on_implausible and "retried_wider_search" not in flags:
        # Landmarks in a wrong pose show as a fit the model cannot explain: predict again with
        # the wider start search and keep the better-explained fit.
        t1 = time.perf_counter()
        pred2 = predict_landmarks(mesh, model=model, options=opts.predict.wider())
        pos2 = {k: np.asarray(v, float) for k, v in pred2.positions.items()}
        reg2 = register(mesh, pos2, template=template, options=reg_opts)
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
