"""The ``bu3dfe-ood`` preset (issue 14): out-of-model subjects (:mod:`.ood`) scanned with the
artefacts of real scans (:mod:`.artefacts`), with the ``bu3dfe`` preset's file layout and exact
ground truth.

Seeds: a subject's identity, feature factors and warp come from ``SeedSequence(seed,
spawn_key=(3, g, n))``, everything random in one scan (artefact plan, scanner, artefacts, pose)
from ``SeedSequence(seed, spawn_key=(4, g, n, e, l))`` (g, n, e, l as in
:mod:`facecorr.synth.generate`): streams of their own, so the preset's subjects are not the
``bu3dfe`` preset's, and the bytes written depend only on the seed.

Extra ground truth beside the ``bu3dfe`` contract: the JSON's ``"split"`` is ``"ood_test"`` or
``"ood_holdout"`` (:func:`facecorr.synth.ood.ood_split`), ``"artefacts"`` lists the artefact
kinds of the scan, ``"artefact_details"`` their settings, ``"ood"`` the subject's identity,
feature factors and warp; the dense npz has ``tri = -1`` for added geometry and
``artefact_label`` (S,) uint8 (:data:`facecorr.synth.artefacts.LABELS`). The landmarks and
iBUG-68 points are placed as in the ``bu3dfe`` preset, then moved onto the true face surface (the
closest point of the head's ICT triangles: at most ~0.5 mm, across the eyelid folds the scan's
triangles bridge).
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from ..geometry.mesh import Mesh
from ..io import save_mesh
from .artefacts import apply_artefacts, artefact_colours, draw_plan, scanner_overrides
from .expressions import EXPRESSION_CODES, expression_weights
from .model import load_ict
from .ood import OODConfig, OODSubject, ood_head, ood_subject
from .scanner import ScannerConfig, closest_point_on_mesh, random_rotation, scan_head

__all__ = ["PRESET", "subject_of", "ood_scan_rng", "make_ood_scan", "ood_model_vertices", "save_ood_scan"]

#: The preset's name.
PRESET = "bu3dfe-ood"


def _gn(subject: str) -> tuple[int, int]:
    return "FM".index(subject[0]), int(subject[1:])


@lru_cache(maxsize=8)
def subject_of(seed: int, subject: str) -> OODSubject:
    """The out-of-model subject ``subject`` (like "F0001") of database ``seed``."""
    g, n = _gn(subject)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3, g, n)))
    return ood_subject(load_ict(), rng, OODConfig())


def ood_scan_rng(seed: int, subject: str, expression: str, level: int) -> np.random.Generator:
    """The generator of everything random in one scan of the preset (module docstring)."""
    g, n = _gn(subject)
    e = EXPRESSION_CODES.index(expression)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(4, g, n, e, level)))


def ood_model_vertices(seed: int, subject: str, expression: str, level: int) -> tuple[np.ndarray, np.ndarray]:
    """The true head of one scan before scanning: ((N, 3) mm model frame, (53,) expression weights);
    with the dense npz's ``pose`` it reproduces ``clean`` as in
    :func:`facecorr.synth.generate.model_vertices`."""
    model = load_ict()
    rng = ood_scan_rng(seed, subject, expression, level)
    alpha = expression_weights(model.expression_names, expression, level, rng)
    return ood_head(model, subject_of(seed, subject), alpha), alpha


def make_ood_scan(seed: int, subject: str, expression: str, level: int, config: ScannerConfig | None = None,
                  plan: dict | None = None):
    """Simulate one scan of the preset.

    ``plan`` replaces the drawn artefact plan (:func:`facecorr.synth.artefacts.draw_plan`; for
    tests and pictures): the plan is still drawn first, so the scanner's random numbers are the
    same whatever plan is given.

    Returns
    -------
    (scan, expression weights (53,), labels (S,) uint8, plan dict, details dict): the Scan in the
    scan frame (pose applied), the per-vertex artefact labels, the artefact plan and what each
    artefact did.
    """
    model = load_ict()
    rng = ood_scan_rng(seed, subject, expression, level)
    alpha = expression_weights(model.expression_names, expression, level, rng)
    V = ood_head(model, subject_of(seed, subject), alpha)
    drawn = draw_plan(rng)
    plan = drawn if plan is None else plan
    base = config or ScannerConfig()
    over = scanner_overrides(plan)
    cfg = replace(base, yaw=0.0, pitch=0.0, roll=0.0, translation=0.0, uniform_rotation=False, **over)
    scan = scan_head(model, V, cfg, rng)  # in the model frame: the artefacts are placed there
    scan, labels, details = apply_artefacts(scan, V, model, plan, rng, cfg.spacing)
    # the annotated points onto the true surface itself (the scanner puts them on its
    # triangulation of it, up to ~0.5 mm off across the eyelid folds)
    scan.landmarks = _onto_surface(scan.landmarks, V, model.triangles)
    found = np.isfinite(scan.ibug68).all(1)
    scan.ibug68[found] = _onto_surface(scan.ibug68[found], V, model.triangles)
    R = random_rotation(rng, base.yaw, base.pitch, base.roll, base.uniform_rotation)
    t = rng.uniform(-base.translation, base.translation, 3)

    def posed(x):
        return x @ R.T + t

    scan.vertices, scan.clean = posed(scan.vertices), posed(scan.clean)
    scan.landmarks, scan.ibug68 = posed(scan.landmarks), posed(scan.ibug68)
    scan.pose = np.concatenate([R, t[:, None]], axis=1)
    scan.info.update(crop=cfg.crop, spacing_mm=cfg.spacing)
    return scan, alpha, labels, plan, details


def _onto_surface(points: np.ndarray, V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(K, 3) closest points of the surface (V, T) to ``points`` (K, 3) mm."""
    d, q = closest_point_on_mesh(np.asarray(points, float), V, T, 10.0)
    return np.where(np.isfinite(d)[:, None], q, points)


def save_ood_scan(path, scan, labels: np.ndarray, colour: str | None, colour_seed: int) -> None:
    """Write the scan: binary PLY (with per-vertex RGB for ``colour="vertex"``), or OBJ + MTL +
    PNG for ``"texture"`` (the skin atlas of :mod:`facecorr.synth.colour` with a strip of the
    artefacts' colours below it)."""
    from .colour import material_positions, scan_texture_coordinates, skin_colour, texture_atlas

    if colour is None:
        save_mesh(path, (scan.vertices, scan.faces))
        return
    skin = (scan.tri >= 0) & (labels == 0)
    palette = artefact_colours(colour_seed)
    if colour == "vertex":
        rgb = np.zeros((len(scan.vertices), 3))
        rgb[skin] = skin_colour(material_positions(scan.tri[skin], scan.bary[skin]))
        for lab, c in palette.items():
            rgb[labels == lab] = c
        save_mesh(path, (scan.vertices, scan.faces), colors=np.round(rgb * 255.0).astype(np.uint8))
        return
    image, _ = texture_atlas()
    h, w = image.shape[:2]
    strip_h = 16
    strip = np.zeros((strip_h, w, 3), np.uint8)
    labs = sorted(palette)
    cell = w // len(labs)
    uv = np.zeros((len(scan.vertices), 2))
    uv[skin] = scan_texture_coordinates(scan.tri[skin], scan.bary[skin])
    uv[:, 1] = (strip_h + uv[:, 1] * h) / (h + strip_h)  # the atlas above the strip
    for k, lab in enumerate(labs):
        strip[:, k * cell:(k + 1) * cell] = np.round(palette[lab] * 255.0).astype(np.uint8)
        sel = labels == lab
        uv[sel] = [((k + 0.5) * cell) / w, 0.5 * strip_h / (h + strip_h)]
    full = np.concatenate([image, strip], axis=0)
    save_mesh(path, Mesh(scan.vertices, scan.faces, face_uv=uv[scan.faces], texture=full))
