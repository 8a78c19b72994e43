"""Eye search: fit the template's eyes to the scan's eye fissures before the shape fit (issue 14).

Out of model the expression-and-identity fit places the template's eyes by the template's own
eye shape: on a face whose eyes are narrower or wider than any training face's the lids end
millimetres beside the scan's eye corners (``ood_test``: inner corners 6-7 mm off on a whole
subject), and the shape fit keeps them there. The template has a hole where the eye is, so its
closest-point matches never notice that the hole covers skin or that the lids cover the eyeball:
nothing pulls the lids across the surface. The scan shows the eyeball through the fissure. With
the front of an eyeball put into the template's hole (the ICT model's own eyeball,
:func:`facecorr.template.eye_caps`), the eye is a relief again: lids closing around a dome
whose cornea stands out, and a hole that may no longer lie over skin. Each eye's region with
its dome is fitted from a ladder of widths (:func:`.feature_search.fit_feature`): a landing
clearly better than where the eye stands (trimmed RMS ≤ ``max_rms_ratio`` × its own) moves the
lids, faded out over ``fade`` mm around them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .feature_search import FeatureSearchOptions, face_axes, fit_feature

#: iBUG-68 indices of each eye's contour, by the template's eye-hole loop name.
EYE_IBUG = {"right_eye": tuple(range(36, 42)), "left_eye": tuple(range(42, 48))}


@dataclass(frozen=True)
class EyeSearchOptions(FeatureSearchOptions):
    """Settings of :func:`search_eyes`: the fields and defaults of
    :class:`~facecorr.registration.feature_search.FeatureSearchOptions`, with widths 0.75-1.25x.

    Measured (BENCHMARKS.md, "Out of model, eleventh pass"): at ``max_rms_ratio`` 0.7 no eye of
    175 in-model test scans moves and 21 of 83 out-of-model scans' eyes improve by > 0.2 mm (2 get
    worse); at 0.8 / 1.0 the in-model eyes lose 4 / 10 %. Moving the whole region (8 + 10 mm)
    dragged the brows and the cheeks (out of model: brows 3.17 -> 3.22 mm, dense 3.61 -> 3.63 on
    the scans that register): the lids only, faded (``move_margin`` 2, ``fade`` 8). Eye openness
    (``y_scales`` (0.85, 1, 1.15)) was no better out of model (2026-12-07, "twelfth pass")."""

    x_scales: tuple = (0.75, 0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2, 1.25)


def search_eyes(vertices: np.ndarray, template, scan, transform: np.ndarray, options: EyeSearchOptions):
    """Where the scan's eyes are, for a fitted template whose eyes may be too wide or narrow.

    Parameters
    ----------
    vertices : (N, 3) the fitted template (expression fit), scan frame, mm.
    template : the Template (its eye-hole loops, iBUG-68 points; frame: x across, y up).
    scan : Mesh (its :attr:`~facecorr.geometry.mesh.Mesh.surface`).
    transform : (3, 4) the template-to-scan alignment (its linear part gives the face's axes).
    options : EyeSearchOptions.

    Returns
    -------
    (vertices (N, 3), info dict): the template with each eye's region moved where its lids fit
    the scan's eye (the input itself when no landing is clearly better), and per eye
    (``right_eye``, ``left_eye``) ``x_scale``, ``y_scale``, ``rms_ratio`` (best landing's trimmed
    RMS / the eye's own where it stands), ``angle_deg``, ``shift_mm`` (the eye centre's move) and
    ``moved``.
    """
    from ..template import eye_caps

    caps = eye_caps(template)
    out = np.asarray(vertices, float).copy()
    axes = face_axes(transform)
    info = {}
    for name in EYE_IBUG:
        cap = caps.get(name)
        if cap is None or len(cap) == 0:
            continue
        e = fit_feature(out, template, scan, axes, EYE_IBUG[name], cap, options)
        if e is not None:
            info[name] = e
    return out, info
