"""Module paths that moved when the package was layered, kept importable.

``facecorr.spatial``, ``facecorr.geodesic`` and ``facecorr.descriptors`` are the documented, stable
public paths of the kernels (they live in ``facecorr.geometry``). The others are the flat layout's
old paths, deprecated for one release: importing one warns and returns the module's new home.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old path -> (new path, deprecated)
ALIASES = {
    "facecorr.spatial": ("facecorr.geometry.spatial", False),
    "facecorr.geodesic": ("facecorr.geometry.geodesic", False),
    "facecorr.descriptors": ("facecorr.geometry.descriptors", False),
    "facecorr.mesh": ("facecorr.geometry.mesh", True),
    "facecorr.curvature": ("facecorr.geometry.curvature", True),
    "facecorr.raster": ("facecorr.geometry.raster", True),
    "facecorr.fileio": ("facecorr.io.atomic", True),
    "facecorr.evaluate": ("facecorr.evaluation.metrics", True),
    "facecorr.registration_eval": ("facecorr.evaluation.registration", True),
    "facecorr.landmarks.evaluate": ("facecorr.evaluation.landmarks", True),
    "facecorr.registration.affine": ("facecorr.registration.alignment", True),
}


class _AliasFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old path to the already-importable module at its new path."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname in ALIASES:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        new, deprecated = ALIASES[spec.name]
        if deprecated:
            warnings.warn(f"{spec.name} is deprecated: use {new}", DeprecationWarning, stacklevel=3)
        return importlib.import_module(new)

    def exec_module(self, module):  # the module is already executed at its new path
        pass


def install() -> None:
    """Put the alias finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.append(_AliasFinder())
