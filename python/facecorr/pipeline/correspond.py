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
from ..registration.beard import BeardOptions, register_under_beard
from ..registration.chin import ChinOptions, register_long_lower_face
from ..registration.neutral import NeutralOptions
from ..registration.register import RegisterOptions
from .mirror import MirrorOptions, mirror_check


@dataclass
class Result:
    """A registered scan.

    Attributes
    ----------
    vertices : (N, 3) float64, the template deformed onto the scan, mm, the scan's frame.
    faces : (M, 3) int64, the template's triangles (the same for every scan).
    landmarks : dict name -> (3,) mm, the landmarks the registration was guided by.
    landmarks_registered : dict name -> (3,) mm, the 8 landmarks read off the registered template.
    point_set : optional dict name -> (3,) mm, a user's points on the template read off this result
        (:mod:`facecorr.template.point_sets`).
    ibug68 : (68, 3) float64 mm, the iBUG-68 points read off the registered template (scan
        frame); NaN rows where the template has no such point (the jaw line beyond its border).
    confidence : dict name -> float in [0, 1] (1 for landmarks given by the user).
    expression_weights : dict blendshape name -> fitted weight in [0, 1].
    mhd : float, modified Hausdorff distance template -> scan, mm.
    coverage : float in [0, 1], the share of the registered template's vertices with scan under
        them (nearest scan vertex within ``CorrespondOptions.coverage_distance`` mm).
    fit_rms : float or None, RMS residual of the expression + identity fit, mm (how well the model
        explains the scan; None when the expression is not fitted).
    surface_distance : (N,) float64 or None, each registered vertex's distance to the scan's
        surface, mm (its closest point on the triangles around its nearest scan vertex, walked on
        to neighbouring triangles while it lies on an edge: ``Mesh.surface.closest``): ~0 where the
        template lies on the scan, growing where it misses it or reaches past its border.
    neutral_vertices : (N, 3) float64 or None, the expression-removed shape: the registered
        template with the fitted expression taken away (same identity, neutral face, same vertex
        order), mm, the scan's frame (:func:`facecorr.registration.neutral.neutral_shape`).
    neutral_removed : dict blendshape name -> weight taken away for it, or None.
    timings_s : dict stage -> seconds.
    flags : list of str, warnings (low-confidence landmarks, ...).
    to_mm, units : the scan's units (results are written back in them).
    uncovered : (N,) bool, the registered vertices with no scan under them (nearest scan vertex
        farther than ``CorrespondOptions.coverage_distance``; ``coverage`` = 1 - its mean).
    colors : (N, 3) float32 RGB in [0, 1], or None when the scan has no colour: the scan's colour
        at each registered vertex's closest scan point (barycentric in per-vertex colours,
        bilinear in a texture; :mod:`facecorr.geometry.colour`). NaN rows where ``uncovered``: no
        colour is invented where the template has no scan under it.
    color_source : "vertex", "texture" or None, where ``colors`` came from.
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
    coverage: float = 1.0
    ibug68: np.ndarray | None = None
    point_set: dict | None = None
    to_mm: float = 1.0
    units: str = "mm"
    fit_rms: float | None = None
    surface_distance: np.ndarray | None = None
    neutral_vertices: np.ndarray | None = None
    neutral_removed: dict | None = None
    uncovered: np.ndarray | None = None
    colors: np.ndarray | None = None
    color_source: str | None = None

    #: The PLY colour of a vertex without colour (``uncovered``): mid-grey, alpha 0.
    UNCOVERED_RGBA = (128, 128, 128, 0)

    def colour_json(self) -> dict | None:
        """The ``"colour"`` entry of the JSON: None when the scan has no colour, else ``{"source":
        "vertex" | "texture", "n_uncovered": k, "uncovered": [vertex ids], "uncovered_marked": how
        the mesh file shows them}``."""
        if self.colors is None:
            return None
        ids = np.flatnonzero(~np.isfinite(np.asarray(self.colors)).all(axis=1))
        return {"source": self.color_source, "n_uncovered": int(len(ids)), "uncovered": ids.tolist(),
                "uncovered_marked": "rgb 128 128 128 with alpha 0 in a PLY (grey without alpha in OBJ / VRML / GLB)"}

    def colour_bytes(self) -> np.ndarray | None:
        """(N, 4) uint8 RGBA written into the mesh file: the colours, alpha 255; uncovered
        vertices :attr:`UNCOVERED_RGBA`. None without colour."""
        if self.colors is None:
            return None
        c = np.asarray(self.colors, dtype=np.float64)
        ok = np.isfinite(c).all(axis=1)
        out = np.empty((len(c), 4), dtype=np.uint8)
        out[:] = self.UNCOVERED_RGBA
        out[ok, :3] = np.round(np.clip(c[ok], 0.0, 1.0) * 255.0).astype(np.uint8)
        out[ok, 3] = 255
        return out

    def to_json(self) -> dict:
        """The JSON contract of ``facecorr register --json`` (coordinates, distances and MHD in the
        scan's units; ``surface_distance`` packed by :func:`encode_distances`)."""
        s = 1.0 / self.to_mm
        return {
            "units": self.units,
            "landmarks": {k: (np.asarray(v) * s).tolist() for k, v in self.landmarks.items()},
            "landmarks_registered": {k: (np.asarray(v) * s).tolist() for k, v in self.landmarks_registered.items()},
            "ibug68": None if self.ibug68 is None else [
                None if not np.isfinite(p).all() else (p * s).tolist() for p in np.asarray(self.ibug68)],
            "confidence": {k: float(v) for k, v in self.confidence.items()},
            "expression_weights": {k: float(v) for k, v in self.expression_weights.items()},
            "mhd": float(self.mhd) * s,
            "coverage": round(float(self.coverage), 4),
            "fit_rms": None if self.fit_rms is None else float(self.fit_rms) * s,
            "surface_distance": None if self.surface_distance is None else encode_distances(self.surface_distance, self.to_mm),
            "timings_s": {k: round(float(v), 4) for k, v in self.timings_s.items()},
            "flags": list(self.flags),
            "colour": self.colour_json(),
            "neutral_expression_removed": None if self.neutral_removed is None else {
                k: float(v) for k, v in self.neutral_removed.items()},
            **({} if self.point_set is None else
               {"point_set": {k: (np.asarray(v) * s).tolist() for k, v in self.point_set.items()}}),
        }

    def save(self, mesh_path, json_path=None, *, neutral_path=None, also=(), inputs=()) -> None:
        """Write the registered template (scan's units) and optionally the JSON and the
        expression-removed shape (``neutral_path``, a mesh file in the scan's units), as a group:
        all are written or none (nothing of them is left on any error).

        ``also``: more files of the same group, pairs ``(path, writer)`` with ``writer(tmp_path)``
        writing the file (e.g. the PNG); ``inputs``: paths the outputs must not overwrite.
        Raises OutputError (or MeshFileError for an unknown mesh format) naming the given path.
        """
        import json
        from pathlib import Path

        from ..io import save_mesh
        from ..io.atomic import atomic_paths, check_output_paths
        from ..io.load import format_of

        mesh_path = Path(mesh_path)
        outputs = [("the mesh", mesh_path)]
        if json_path is not None:
            outputs.append(("the JSON", Path(json_path)))
        if neutral_path is not None:
            if self.neutral_vertices is None:
                raise ValueError("this result has no neutral shape (CorrespondOptions.neutral was None)")
            also = [(neutral_path, lambda tmp: save_mesh(tmp, (self.neutral_vertices / self.to_mm, self.faces))),
                    *also]
            format_of(Path(neutral_path))
        outputs += [("an output", Path(p)) for p, _ in also]
        check_output_paths(outputs, inputs=inputs)
        format_of(mesh_path)  # an unknown mesh format, named by the user's path
        with atomic_paths(*(p for _, p in outputs)) as tmps:
            save_mesh(tmps[0], (self.vertices / self.to_mm, self.faces), colors=self.colour_bytes())
            k = 1
            if json_path is not None:
                tmps[1].write_text(json.dumps(self.to_json(), indent=2) + "\n")
                k = 2
            for (_, writer), tmp in zip(also, tmps[k:]):
                writer(tmp)


#: ``surface_distance`` in the JSON: one byte a vertex, this many mm a step (255: this x 255 or more).
DISTANCE_STEP_MM = 0.02


def encode_distances(distance_mm, to_mm: float = 1.0) -> dict:
    """Per-vertex distances (N,) mm packed for the result JSON, in the scan's units (``to_mm`` mm a
    unit): ``{"encoding": "uint8-base64", "step": s, "data": ...}`` with distance = byte x s, the
    byte 255 meaning 255 s or more (5.1 mm). ~7 kB for the template's vertices, 0.01 mm rounding."""
    import base64

    d = np.asarray(distance_mm, dtype=np.float64)
    codes = np.clip(np.rint(np.nan_to_num(d, nan=np.inf) / DISTANCE_STEP_MM), 0, 255).astype(np.uint8)
    return {"encoding": "uint8-base64", "step": DISTANCE_STEP_MM / to_mm, "data": base64.b64encode(codes.tobytes()).decode("ascii")}


def decode_distances(packed) -> np.ndarray:
    """(N,) float64 distances in the JSON's units from :func:`encode_distances`' dict; ValueError
    (a one-line reason) when it is not one."""
    import base64
    import binascii

    if not isinstance(packed, dict) or packed.get("encoding") != "uint8-base64":
        raise ValueError("surface_distance is not a {\"encoding\": \"uint8-base64\", ...} object")
    step, data = packed.get("step"), packed.get("data")
    if isinstance(step, bool) or not isinstance(step, (int, float)) or not step > 0 or not isinstance(data, str):
        raise ValueError("surface_distance needs a positive \"step\" and a base64 \"data\" string")
    try:
        codes = np.frombuffer(base64.b64decode(data, validate=True), dtype=np.uint8)
    except (binascii.Error, ValueError):
        raise ValueError("surface_distance data is not base64") from None
    return codes.astype(np.float64) * float(step)


@dataclass(frozen=True)
class CorrespondOptions:
    """Settings of :func:`correspond`: the two stages' options and how the pipeline joins them.

    ``predicted_landmark_weight`` replaces ``register.shape.w_landmark`` when the landmarks were
    predicted: the shape fit's landmark term pins the template's landmarks to the given points,
    right for landmarks a user supplies, harmful for predicted ones (2-3 mm off; BENCHMARKS.md,
    "Where the defaults come from"). ``refit_on_implausible``: a fit the model cannot explain
    (:meth:`RegistrationResult.implausible`) is redone once from landmarks predicted with the wider
    start search (:meth:`PredictOptions.wider`) and from the start search's next best distinct
    poses (``PredictOptions.n_alternative_poses``) and from the first search with
    ``refit_poses_per_tip`` poses per nose-tip candidate, and the best-explained fit kept: the lowest fit
    RMS (mm) plus ``refit_identity_cost`` mm per unit of the identity weights' squared norm ‖β‖²
    (:func:`refit_score`); then the start search with the template resized to each of
    ``refit_pose_scales``, whose fit is kept only if it is also plausible.
    """

    predict: PredictOptions = field(default_factory=PredictOptions)
    register: RegisterOptions = field(default_factory=RegisterOptions)
    predicted_landmark_weight: float = 0.0
    refit_on_implausible: bool = True
    # Of the refits, a face the identity model finds implausible (‖β‖² of 200-550 for 40 modes,
    # where faces like the training faces have ~40) pays this many mm of fit RMS per unit of ‖β‖²:
    # on raw crops and unusual faces a fit on the wrong part can match the scan a little closer
    # (BENCHMARKS.md, "Out of model, fourth pass"; 0: the lowest RMS alone).
    refit_identity_cost: float = 0.003
    # After those tries, the start search again with the template at each of these sizes (a face
    # 0.73-0.88x the template's size, as on 14 of the 25 gross failures out of model, fits no pose
    # of the full-size template); its fit replaces the best one only if it is better *and* the
    # model explains it (not implausible): a smaller template also fits wrong parts of a scan
    # closer (BENCHMARKS.md, "Out of model, ninth pass"; () : no sized try).
    refit_pose_scales: tuple = (0.8,)
    # Before the wider search, the first start search again with this many poses per nose-tip
    # candidate scored by the whole template (0: no such try). An unusual face in a strong
    # expression (disgust, anger) can fit the template's upper face better turned by 60-90 deg
    # about the nose than upright, so that the upright pose ranks third for its nose tip and is
    # never scored; the whole template's score then picks it (BENCHMARKS.md, "Out of model,
    # thirteenth pass"). As the default of every search it fixed the same two `ood_test` scans but
    # made two others 1.3-1.6 mm worse and moved 12 in-model scans (7 worse): here only the fits
    # the model cannot explain see it.
    refit_poses_per_tip: int = 3
    # Given landmarks farther than this from every scan vertex (mm) are refused: they are in
    # another frame or unit, and the registration would land beside the scan.
    max_landmark_distance: float = 10.0
    # A registered vertex with a scan vertex within this distance (mm) counts as covered; the
    # registered landmarks farther than ``off_surface_distance`` are flagged by name.
    coverage_distance: float = 3.0
    off_surface_distance: float = 5.0
    # A result whose coverage is below this is flagged (a half face, a large hole); correct
    # registrations of cropped scans cover 0.90-0.93 (10 bu3dfe test scans; the template reaches
    # past a scan's border).
    min_coverage: float = 0.6
    # Pieces with at least this share of the largest piece's area count as separate surfaces
    # (several faces or a face cut in two); smaller ones are specks and hair.
    large_piece_fraction: float = 0.2
    # Predicted landmarks only: register this many more times, each time guided by the 8
    # landmarks read off the previous registration (the whole template fitted to the scan places
    # them better than the local patch fits that predicted them).
    refine_passes: int = 0
    # The expression-removed shape (Result.neutral_vertices; None: not computed). See
    # facecorr.registration.neutral.
    neutral: NeutralOptions | None = field(default_factory=NeutralOptions)
    # A beard (a rough layer over the lower face, facecorr.registration.beard) is left out of the
    # shape fit, which is redone without it (None: off; flag ``beard``).
    beard: BeardOptions | None = field(default_factory=BeardOptions)
    # ChinOptions(): a scan whose chin goes on facing forward well below the fitted template's (a
    # lower face longer than the model's) gets its lower face stretched and the shape fit redone
    # (facecorr.registration.chin; flag ``long_lower_face``). Off by default: it rescued the long
    # lower faces of ood_test (dense 6.11 -> 5.83 mm) but fired on 5 of the 42 held-back scans,
    # faces the template already fitted, and made all 5 worse (dense 14.00 -> 14.44 mm;
    # BENCHMARKS.md, "Out of model, fifteenth pass").
    chin: ChinOptions | None = None
    # Predicted landmarks only: a fit about whose mid-plane the scan is clearly asymmetric is
    # redone from a pose turned onto the scan's own symmetry plane (facecorr.pipeline.mirror;
    # None: off; flag ``mirror_turned``).
    mirror: MirrorOptions | None = field(default_factory=MirrorOptions)


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
    work, offset = mesh.centred_outward()  # where the scan sits, and its winding, must not change the answer
    if landmarks is None:
        pred = predict_landmarks(work, model=model, options=opts.predict)
        positions = {k: np.asarray(v, float) for k, v in pred.positions.items()}
        confidence = dict(pred.confidence)
        flags += list(pred.flags)
        timings.update({f"landmarks.{k}": v for k, v in pred.timings_s.items()})
    else:
        positions = _given_landmarks(landmarks, work, offset, opts.max_landmark_distance)
        confidence = {n: 1.0 for n in LANDMARK_NAMES}
    timings["landmarks"] = time.perf_counter() - t0
    reg_opts = opts.register
    if landmarks is None:
        reg_opts = replace(reg_opts, shape=replace(reg_opts.shape, w_landmark=opts.predicted_landmark_weight))
    reg = register(work, positions, template=template, options=reg_opts)
    doubts = reg.implausible()
    if doubts and landmarks is None and opts.refit_on_implausible:
        # Landmarks in a wrong pose show as a fit the model cannot explain: predict again with
        # the wider start search and keep the better-explained fit. Also when the prediction
        # already retried that search and kept its first answer (both failed its own checks):
        # the registration's residual judges the two better than the landmark checks.
        t1 = time.perf_counter()
        # The start search's other readings of the scan go first: on raw crops and unusual faces
        # a shoulder or a hairy scalp can outscore the face in the rigid ranking, while the
        # deformable fit from the face explains the scan far better (BENCHMARKS.md, issue 14).
        tries = [dict(start_pose=p) for p in pred.debug.get("alternative_poses", [])]
        if int(opts.refit_poses_per_tip) > 0:
            tries.append(dict(options=replace(opts.predict, poses_per_tip=int(opts.refit_poses_per_tip), retry=False)))
        tries.append(dict(options=replace(opts.predict.wider(), retry=False)))
        n_unsized = len(tries)
        tries += [dict(options=replace(opts.predict, pose_scales=(float(s),), retry=False))
                  for s in opts.refit_pose_scales]
        for i_try, how in enumerate(tries):
            pred2 = predict_landmarks(work, model=model, **({"options": opts.predict} | how))
            pos2 = {k: np.asarray(v, float) for k, v in pred2.positions.items()}
            reg2 = register(work, pos2, template=template, options=reg_opts)
            if i_try >= n_unsized and reg2.implausible():
                continue  # a resized template's fit must convince the model on its own
            if refit_score(reg2, opts.refit_identity_cost) < refit_score(reg, opts.refit_identity_cost):
                reg, positions, confidence = reg2, pos2, dict(pred2.confidence)
                flags = list(pred2.flags)  # the first prediction's doubts no longer apply
                if i_try >= n_unsized:
                    flags.append(f"small_face:found with the template at {how['options'].pose_scales[0]:.2f}x")
                doubts = reg.implausible()
        timings["refit"] = time.perf_counter() - t1
        flags.append("refit_wider_search_after_implausible_fit")
    if landmarks is None and not doubts:
        for _ in range(int(opts.refine_passes)):
            t1 = time.perf_counter()
            pos2 = {k: np.asarray(v, float) for k, v in reg.landmarks_registered.items()}
            reg2 = register(work, pos2, template=template, options=reg_opts)
            timings["refine"] = timings.get("refine", 0.0) + time.perf_counter() - t1
            if reg2.implausible():
                break
            reg, positions = reg2, pos2
    if opts.mirror is not None and landmarks is None:
        t1 = time.perf_counter()

        def redo(start_pose):
            pred2 = predict_landmarks(work, model=model, options=opts.predict, start_pose=start_pose)
            pos2 = {k: np.asarray(v, float) for k, v in pred2.positions.items()}
            return register(work, pos2, template=template, options=reg_opts), pos2, dict(pred2.confidence), list(pred2.flags)

        redone, info = mirror_check(work, reg, template, opts.mirror, redo)
        if redone is not None:
            reg, positions, confidence = redone[0], redone[1], redone[2]
            flags = list(redone[3])  # the first prediction's doubts no longer apply
            flags.append(f"mirror_turned:the fit's midline was {info['turn_deg']:.0f} deg and "
                         f"{abs(info['offset_mm']):.0f} mm off the scan's symmetry plane (asymmetry "
                         f"{info['asymmetry']:.1f} -> {info['redone_asymmetry']:.1f} mm); registered again from there")
            doubts = reg.implausible()
        if info["final"] > opts.mirror.flag_asymmetry:
            flags.append(f"asymmetric_fit:the scan is {info['final']:.1f} mm asymmetric about the registered midline "
                         f"(correct fits: under 1 mm in model, 2 mm on raw crops); a wrong pose is likely")
        timings["mirror"] = time.perf_counter() - t1
    if opts.chin is not None and reg.shape_start is not None and reg_opts.fit_shape and reg.transform is not None:
        # A lower face longer than the model's: the template slid up the scan's (opt-in).
        t1 = time.perf_counter()
        reg, chin = register_long_lower_face(work, reg, positions, template, reg_opts, opts.chin)
        if chin["kept"]:
            flags.append(f"long_lower_face:the scan's chin went on {chin['extent']:.0f} mm below the template's; lower "
                         f"face stretched by {chin['stretch']:.0f} mm")
            doubts = reg.implausible()
        timings["chin"] = time.perf_counter() - t1
    if opts.beard is not None and reg.shape_start is not None and reg_opts.fit_shape:
        # A beard's rough layer stands 3-10 mm in front of the skin: the shape fit is redone
        # without it (BENCHMARKS.md, "Out of model, fourteenth pass").
        t1 = time.perf_counter()
        reg, beard = register_under_beard(work, reg, positions, template, reg_opts, opts.beard,
                                          lambda r: refit_score(r, opts.refit_identity_cost))
        if beard["beard"]:
            what = "the registration" if beard["how"] == "register" else "the shape fit"
            flags.append(f"beard:{beard['n_rough']} rough scan vertices ({100 * beard['share']:.0f} % of the lower "
                         f"face) left out of {what}")
            doubts = reg.implausible()
        timings["beard"] = time.perf_counter() - t1
    flags += [f"implausible_fit:{d}" for d in doubts]
    mouth = reg.details.get("mouth_search") or {}
    if mouth.get("moved"):
        flags.append(f"mouth_moved:{mouth['shift_mm']:.1f}mm (the lips fit the scan better there than where the "
                     f"face model put them)")
    for eye, e in (reg.details.get("eye_search") or {}).items():
        if e.get("moved") and (e["x_scale"] != 1.0 or e["y_scale"] != 1.0 or e["shift_mm"] >= 2.0):
            flags.append(f"eye_moved:{eye} {e['shift_mm']:.1f}mm, {e['x_scale']:.2f}x as wide (the lids fit the scan's "
                         f"eye better there than where the face model put them)")
    nose = (reg.details.get("nose_search") or {}).get("nose") or {}
    if nose.get("moved") and (nose["x_scale"] != 1.0 or nose["y_scale"] != 1.0 or nose["shift_mm"] >= 2.0):
        flags.append(f"nose_moved:{nose['shift_mm']:.1f}mm, {nose['x_scale']:.2f}x as wide (the nose fits the scan's "
                     f"better there than where the face model put it)")
    ids = np.asarray(template.landmark_ids)
    for name, d in zip(LANDMARK_NAMES, reg.scan_distance[ids]):
        if d > opts.off_surface_distance:
            flags.append(f"landmark_off_surface:{name} ({d:.1f} mm from the scan)")
    areas = mesh.component_areas
    n_large = int(np.sum(areas >= opts.large_piece_fraction * areas[0]))
    if n_large > 1:
        flags.append(f"several_pieces:{n_large} large pieces (the registration used the one under the landmarks)")
    uncovered = reg.scan_distance > opts.coverage_distance
    coverage = float(np.mean(~uncovered))
    surface = work.surface.closest(np.ascontiguousarray(reg.vertices, dtype=np.float64), 1)[3]
    if coverage < opts.min_coverage:
        flags.append(f"low_coverage:{100 * coverage:.0f}% of the template has scan under it")
    timings.update({f"registration.{k}": v for k, v in reg.timings_s.items()})
    colors = None
    if work.color_source is not None:
        t1 = time.perf_counter()
        colors = transfer_colours(work, reg.vertices, uncovered)
        timings["colour"] = time.perf_counter() - t1
    if mesh.meta.get("colour_note"):
        flags.append(f"colour_not_used:{mesh.meta['colour_note']}")
    neutral = removed = None
    if opts.neutral is not None:
        from ..registration.neutral import neutral_shape

        t1 = time.perf_counter()
        neutral, alpha_removed = neutral_shape(reg.vertices, template, options=opts.neutral)
        neutral = neutral + offset
        removed = {str(n): float(a) for n, a in zip(template.blendshape_names, alpha_removed)}
        timings["neutral"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    return Result(
        vertices=reg.vertices + offset,
        faces=np.asarray(template.faces, dtype=np.int64),
        landmarks={k: np.asarray(v) + offset for k, v in positions.items()},
        landmarks_registered={k: np.asarray(v) + offset for k, v in reg.landmarks_registered.items()},
        confidence=confidence,
        expression_weights={str(n): float(a) for n, a in zip(template.blendshape_names, reg.alpha)},
        mhd=float(reg.mhd),
        timings_s=timings,
        flags=flags,
        coverage=coverage,
        ibug68=_ibug68_points(reg.vertices + offset, template),
        to_mm=mesh.to_mm,
        units=mesh.units,
        fit_rms=reg.details.get("fit_rms_mm"),
        surface_distance=surface,
        uncovered=uncovered,
        colors=colors,
        color_source=work.color_source,
        neutral_vertices=neutral,
        neutral_removed=removed,
    )


def refit_score(reg, identity_cost: float) -> float:
    """How badly the model explains a registration (lower is better), to choose among refits: its
    expression + identity fit RMS (mm, inf without one) plus ``identity_cost`` (mm) times ‖β‖², the
    squared norm of its identity weights (χ²-distributed for faces like the training faces)."""
    rms = reg.details.get("fit_rms_mm", np.inf)
    beta = np.asarray(reg.details.get("identity_weights", []), dtype=np.float64)
    return float(rms) + float(identity_cost) * float(beta @ beta)


def transfer_colours(scan: Mesh, vertices: np.ndarray, uncovered: np.ndarray) -> np.ndarray:
    """(N, 3) float32 colours of ``scan`` at the closest scan point of each of ``vertices`` (mm, the
    scan's frame), NaN rows where ``uncovered`` (N,) bool is set."""
    from ..geometry.colour import colours_at

    out = np.full((len(vertices), 3), np.nan, dtype=np.float32)
    keep = ~np.asarray(uncovered, dtype=bool)
    if keep.any():
        out[keep] = colours_at(scan, np.asarray(vertices)[keep])[0]
    return out


def _given_landmarks(landmarks, work: Mesh, offset, max_distance: float) -> dict:
    """The user's 8 landmarks (scan frame, mm) as name -> (3,) float64 in the frame of ``work`` (the
    scan moved by -``offset``), checked: all present, 3 finite numbers each, and on the scan (within
    ``max_distance`` mm of a vertex). Raises LandmarkError."""
    from ..errors import LandmarkError

    if not isinstance(landmarks, dict):
        raise LandmarkError(f"landmarks must be a dict name -> [x, y, z], got {type(landmarks).__name__}")
    missing = [n for n in LANDMARK_NAMES if n not in landmarks]
    if missing:
        raise LandmarkError(f"landmarks given without {', '.join(missing)}")
    out = {}
    for n in LANDMARK_NAMES:
        try:
            p = np.asarray(landmarks[n], dtype=np.float64)
        except (TypeError, ValueError):
            p = np.zeros(0)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise LandmarkError(f"landmark {n} must be 3 finite numbers [x, y, z], got {landmarks[n]!r}")
        out[n] = p - offset
    d, _ = work.kdtree.query(np.array([out[n] for n in LANDMARK_NAMES]))
    far = [(n, float(x)) for n, x in zip(LANDMARK_NAMES, np.asarray(d)) if x > max_distance]
    if far:
        worst = max(far, key=lambda f: f[1])
        raise LandmarkError(f"{len(far)} of the 8 landmarks are not on the scan ({worst[0]} is {worst[1]:.0f} mm from "
                            f"it, more than {max_distance:g} mm): are they in the scan's frame and units?")
    return out


def _ibug68_points(vertices: np.ndarray, template) -> np.ndarray:
    """(68, 3) the template's iBUG-68 vertices in ``vertices`` (mm); NaN where it has none."""
    ids = np.asarray(template.ibug68, dtype=np.int64)
    out = np.full((len(ids), 3), np.nan)
    out[ids >= 0] = vertices[ids[ids >= 0]]
    return out
