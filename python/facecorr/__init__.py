"""facecorr: fully automatic expression-invariant dense correspondence between 3D face scans.

Heavy kernels (KD-tree, geodesics, Finger Print descriptors, curvature, shape fitting) are in the
compiled Rust core ``facecorr._core``; this package holds the method's logic, I/O and the CLI.

Main entry points::

    mesh = facecorr.load_mesh("scan.wrl")            # any pose, units inferred
    lms = facecorr.predict_landmarks(mesh)            # 8 landmarks + confidence
    result = facecorr.correspond(mesh)                # template registered onto the scan
    result.save("registered.ply", "registered.json")
"""

from . import descriptors, errors, geodesic, spatial
from ._core import __version__
from .io import load_mesh, save_mesh
from .mesh import Mesh

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
