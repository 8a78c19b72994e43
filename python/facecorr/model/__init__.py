"""Statistical shape models of registered faces (``facecorr model build | show | export | eval``).

Registered scans share the template's vertex order, so a population of them is a point
distribution model once pose (and optionally size) is removed::

    model = facecorr.model.build_model("results/", variance=0.98)   # a `facecorr batch` folder
    model.save("model.npz")
    alpha, recon = model.project(vertices_mm)     # coefficients (std devs), closest model shape
    d = model.mahalanobis(vertices_mm)
    face = model.sample([2.0, -1.0])              # mean + 2 sd of mode 1 - 1 sd of mode 2

Modules: :mod:`.procrustes` (generalized Procrustes alignment), :mod:`.pca` (PCA by the Gram
matrix), :mod:`.shape_model` (:class:`ShapeModel` and its npz file), :mod:`.results` (reading a
results folder, and which results are used), :mod:`.build` (:func:`fit_model`,
:func:`build_model`, :class:`BuildOptions`), :mod:`.distributed` (the same build on a Dask
cluster: :func:`~.distributed.build_model_on_cluster`), :mod:`.evaluate` (leave-one-out
reconstruction error), :mod:`.export` (statismo HDF5, PLY meshes of the modes).
"""

from .build import BuildOptions, build_model, fit_model
from .pca import principal_components
from .procrustes import generalized_procrustes
from .results import read_results
from .shape_model import ShapeModel

__all__ = ["ShapeModel", "BuildOptions", "build_model", "fit_model", "generalized_procrustes",
           "principal_components", "read_results"]
