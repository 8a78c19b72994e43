"""Fitting a shape model: Procrustes alignment, then PCA of the aligned shapes.

:func:`fit_model` works on shapes in memory; :func:`build_model` reads a results folder first
(:func:`facecorr.model.results.read_results`). Settings are the fields of :class:`BuildOptions`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShapeModelError
from ..options import resolve
from .pca import principal_components
from .procrustes import generalized_procrustes
from .shape_model import ShapeModel


@dataclass(frozen=True)
class BuildOptions:
    """Settings of :func:`fit_model` / :func:`build_model`.

    ``modes``: keep this many modes (None: by ``variance``); ``variance``: keep the fewest modes
    explaining this share of the total variance (0 < variance <= 1). ``scale``: similarity
    alignment (size removed) instead of rigid (size kept as shape variation).
    ``include_flagged``: also use results whose flags doubt the registration
    (:data:`facecorr.model.results.DOUBTFUL_FLAGS`). ``max_iterations`` / ``tolerance``: the
    Procrustes mean update (:func:`generalized_procrustes`).
    """

    modes: int | None = None
    variance: float = 0.98
    scale: bool = False
    include_flagged: bool = False
    max_iterations: int = 100
    tolerance: float = 1e-9

    def check(self) -> None:
        """Raise ShapeModelError for settings out of range."""
        if self.modes is not None and (isinstance(self.modes, bool) or int(self.modes) != self.modes
                                       or self.modes < 1):
            raise ShapeModelError(f"modes must be a whole number >= 1, got {self.modes!r}")
        if not (0.0 < float(self.variance) <= 1.0):
            raise ShapeModelError(f"variance must be a share in (0, 1], got {self.variance!r}")


def fit_model(shapes, faces, names=None, *, source: str = "registered", reference=None, options=None,
              **overrides) -> ShapeModel:
    """A shape model of ``shapes`` (S >= 2, N, 3) mm in correspondence, each in any pose.

    Parameters
    ----------
    shapes : (S, N, 3) float mm; faces : (M, 3) int, their common triangles.
    names : optional S names stored in the model (default "0", "1", ...).
    source : "registered" or "neutral", recorded in the model.
    reference : optional (N, 3) mm: the model is put in this shape's frame (the packaged template
        when the shapes have its vertex count; else the first shape's orientation).
    options : BuildOptions; ``**overrides`` change its fields (``modes=10``, ``scale=True``...).

    Returns
    -------
    ShapeModel, with ``scores`` the shapes' coefficients.
    """
    opts = resolve(options, BuildOptions, overrides, "fit_model")
    opts.check()
    x = np.asarray(shapes, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or len(x) < 2:
        raise ShapeModelError(f"a shape model needs at least 2 shapes of (N, 3) vertices, got an array {x.shape}")
    if not np.isfinite(x).all():
        raise ShapeModelError("the shapes hold NaN or infinite coordinates")
    names = [str(i) for i in range(len(x))] if names is None else [str(n) for n in names]
    if len(names) != len(x):
        raise ShapeModelError(f"{len(names)} names for {len(x)} shapes")
    if reference is None:
        from ..template import load_template

        t = load_template()
        reference = t.vertices if t.n_vertices == x.shape[1] else None
    gpa = generalized_procrustes(x, scale=opts.scale, reference=reference,
                                 max_iterations=opts.max_iterations, tolerance=opts.tolerance)
    pca = principal_components(gpa.aligned.reshape(len(x), -1), modes=opts.modes,
                               variance=None if opts.modes is not None else opts.variance)
    return model_from_pca(pca, faces, names, source=source, options=opts)


def model_from_pca(pca, faces, names, *, source: str, options: BuildOptions) -> ShapeModel:
    """The ShapeModel of ``pca`` (a :class:`facecorr.model.pca.PCA` of S aligned shapes, rows of
    3N mm) with the training shapes' ``names`` (S) and ``faces`` (M, 3). Raises ShapeModelError
    when the shapes did not vary."""
    n_scans = len(pca.scores)
    if len(pca.variances) == 0:
        raise ShapeModelError(f"the {n_scans} shapes are identical after alignment: there is no variation to model")
    n = len(pca.mean) // 3
    std = np.sqrt(pca.variances)
    return ShapeModel(mean=pca.mean.reshape(n, 3), components=pca.components.reshape(-1, n, 3),
                      variances=pca.variances, faces=np.asarray(faces), names=list(names), n_scans=n_scans,
                      scores=pca.scores / std, alignment="similarity" if options.scale else "rigid",
                      source=source, total_variance=pca.total_variance)


def build_model(results_dir, *, neutral: bool = False, options=None, progress: bool = True,
                **overrides) -> ShapeModel:
    """A shape model of the registration results under ``results_dir`` (``facecorr batch``
    output): the registered templates, or with ``neutral`` their expression-removed shapes
    (``<stem>_neutral.ply``). Which results are used: :mod:`facecorr.model.results`.

    ``options`` / ``**overrides``: :class:`BuildOptions`. Raises ShapeModelError (one line).
    """
    from .results import read_results

    opts = resolve(options, BuildOptions, overrides, "build_model")
    opts.check()
    rs = read_results(results_dir, neutral=neutral, include_flagged=opts.include_flagged, progress=progress)
    return fit_model(rs.shapes, rs.faces, rs.names, source="neutral" if neutral else "registered", options=opts)
