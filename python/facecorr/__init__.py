"""facecorr: fully automatic expression-invariant dense correspondence between 3D face scans.

Heavy kernels (KD-tree, geodesics, Finger Print descriptors, curvature, shape fitting) are in the
compiled Rust core ``facecorr._core``; this package holds the method's logic, I/O and the CLI.
"""

from . import errors
from ._core import __version__

__all__ = ["errors", "__version__"]
