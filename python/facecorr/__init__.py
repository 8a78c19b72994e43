"""facecorr: fully automatic expression-invariant dense correspondence between 3D face scans.

Heavy kernels (KD-tree, geodesics, Finger Print descriptors, curvature, shape fitting) are in the
compiled Rust core ``facecorr._core``; this package holds the method's logic, I/O and the CLI.

Main entry points::

    mesh = facecorr.load_mesh("scan.wrl")            # any pose, units inferred
    lms = facecorr.predict_landmarks(mesh)            # 8 landmarks + confidence
    result = facecorr.correspond(mesh)                # template registered onto the scan
    result.save("registered.ply", "registered.json")

The layer rule: the package is built in floors, and a module imports only from its own package
or from a lower floor (never upwards, never sideways between two packages of one floor);
``tests/test_layers.py`` reads every import, function-level ones too, and enforces it.

    7  cli                              every sub-command; nothing imports it
    6  evaluation, model, report        tables and metrics on a synthetic database; shape models; a batch's report page
    5  pipeline                         one scan end to end; many scans (batch)
    4  landmarks, registration          the two stages
    3  template, synth, render          the template, the synthetic database, all plotting
    2  io                               meshes in and out, atomic writes
    1  geometry                         Mesh, KD-tree, ICP, geodesics, descriptors, curvature, transforms
    0  errors, names, options, threads, chi2, _core   the base
"""

from . import errors
from ._aliases import install as _install_aliases
from ._core import __version__
from .geometry import descriptors, geodesic, spatial
from .geometry.mesh import Mesh
from .io import load_mesh, save_mesh

_install_aliases()

__all__ = [
    "Mesh", "load_mesh", "save_mesh", "predict_landmarks", "correspond", "load_template",
    "errors", "spatial", "geodesic", "descriptors", "__version__",
]


def __getattr__(name):
    # The method's stages import lazily: `import facecorr` stays quick for I/O and kernels.
    if name == "predict_landmarks":
        from .landmarks import predict_landmarks

        return predict_landmarks
    if name == "correspond":
        from .pipeline import correspond

        return correspond
    if name == "load_template":
        from .template import load_template

        return load_template
    raise AttributeError(f"module 'facecorr' has no attribute {name!r}")
