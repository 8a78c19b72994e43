"""Nose search: fit the template's lower nose (tip, alae, nostrils, subnasal) to the scan's before
the shape fit (issue 14), as :mod:`.eyes` does for the lids.

Out of model the expression-and-identity fit leaves a nose wider, narrower, longer or shorter than
any training face's where the face model puts it: the template's alae and subnasal end 2-4 mm
beside the scan's (``ood_test``: subalare 2.0-2.2 mm off on the scans that register, 0.6-0.7 in
model), and the shape fit's closest points slide along the nose's sides rather than carry them.
The lower nose has relief of its own (the tip, the alar grooves, the nostrils, the columella), so
its region fitted by trimmed ICP from a ladder of widths (:func:`.feature_search.fit_feature`)
lands on the scan's; a landing clearly better than where the nose stands moves it, faded out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .feature_search import FeatureSearchOptions, face_axes, fit_feature

#: iBUG-68 indices of the lower nose: the tip (30) and the nose base (31-35: alae, nostrils, subnasal).
NOSE_IBUG = tuple(range(30, 36))


@dataclass(frozen=True)
class NoseSearchOptions(FeatureSearchOptions):
    """Settings of :func:`search_nose`: the fields and defaults of
    :class:`~facecorr.registration.feature_search.FeatureSearchOptions` (widths 0.8-1.2x), but a
    landing is taken at <= 0.8x the nose's own RMS. Measured (BENCHMARKS.md, "Out of model,
    twelfth pass"): on the ``ood_test`` scans that register the nose goes 1.69 -> 1.56 mm at 0.7,
    1.52 at 0.8, 1.46 at 1.0; in model it stays 0.62 at 0.7 and 0.8 and loses 6 % at 1.0."""

    max_rms_ratio: float = 0.8


def search_nose(vertices: np.ndarray, template, scan, transform: np.ndarray, options: NoseSearchOptions):
    """Where the scan's lower nose is, for a fitted template whose nose may be off.

    Parameters
    ----------
    vertices : (N, 3) the fitted template (after the expression fit), scan frame, mm.
    template : the Template (its iBUG-68 points; frame: x across, y up).
    scan : Mesh (its :attr:`~facecorr.geometry.mesh.Mesh.surface`).
    transform : (3, 4) the template-to-scan alignment (its linear part gives the face's axes).
    options : NoseSearchOptions.

    Returns
    -------
    (vertices (N, 3), info dict): the template with its lower nose moved where it fits the scan's
    (the input itself when no landing is clearly better), and under ``nose`` the landing's
    ``x_scale``, ``y_scale``, ``rms_ratio``, ``angle_deg``, ``shift_mm`` and ``moved`` (as one
    eye's of :func:`.eyes.search_eyes`; empty when the region is not searched).
    """
    out = np.asarray(vertices, float).copy()
    e = fit_feature(out, template, scan, face_axes(transform), NOSE_IBUG, None, options)
    return out, ({} if e is None else {"nose": e})
