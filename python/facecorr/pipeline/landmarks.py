"""The 8 landmarks read off the registered template: landmark prediction refined by the whole fit.

:func:`facecorr.landmarks.predict_landmarks` places each landmark by a local fit of a patch of the
template around it (:mod:`facecorr.landmarks.patches`): a rigid patch, so an eye wider or a nose
longer than the template's pulls it off by the difference. The registration that follows
(alignment, expression + identity fit, shape fit) fits the whole template to the scan, and the
template's 8 landmark vertices then sit far closer to the truth: on 70 bu3dfe test scans 0.74 mm
mean against 2.22 mm predicted; on the 98 out-of-model ``ood_test`` scans the median scan's mean
2.60 against 6.70 mm, all 8 within 10 mm on 75.5 % against 27.6 % of the scans (``benches/
variants.py``, BENCHMARKS.md "Out of model, second pass"). :func:`locate_landmarks` returns those,
at the cost of one registration (``refine=False``: the prediction alone).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..landmarks.predict import LandmarkResult


def locate_landmarks(mesh, *, model=None, template=None, refine: bool = True, options=None) -> LandmarkResult:
    """The 8 landmarks of a scan, mm, in the mesh's frame.

    Parameters
    ----------
    mesh : facecorr.Mesh (mm, any pose).
    model : landmark model (None: the packaged one); template : Template (None: the packaged one).
    refine : True (default): predict, register the template (:func:`.correspond`, without the
        neutral shape) and read the landmarks off the registered template; False: the prediction.
    options : CorrespondOptions (its ``predict`` field is used alone when ``refine`` is False).

    Returns
    -------
    LandmarkResult: ``positions`` name -> (3,) mm; ``confidence`` and ``flags`` of the prediction
    (and, refined, the registration's flags); ``timings_s``; refined, ``debug["predicted"]`` holds
    the predicted positions the registration started from.
    """
    from .correspond import CorrespondOptions, correspond
    from ..landmarks.predict import predict_landmarks

    opts = options if options is not None else CorrespondOptions()
    if not refine:
        return predict_landmarks(mesh, model=model, options=opts.predict)
    res = correspond(mesh, model=model, template=template, options=replace(opts, neutral=None))
    return LandmarkResult(
        positions={k: np.asarray(v, dtype=np.float64).copy() for k, v in res.landmarks_registered.items()},
        confidence=dict(res.confidence), flags=list(res.flags), timings_s=dict(res.timings_s),
        debug={"predicted": {k: np.asarray(v) for k, v in res.landmarks.items()}})
