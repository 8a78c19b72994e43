"""Reading and writing face scans: meshes (OBJ, PLY, STL, OFF, GLB, VRML 2.0) and BU-3DFE landmarks.

The modules, one concern each (this package re-exports their public names):

* :mod:`.load`   -- :func:`load_mesh` (format dispatch, trimesh readers, validation and cleaning,
  the counts in ``mesh.meta``, the scan's colour kept through it), :func:`infer_units`,
  ``UNIT_TO_MM``, ``MESH_FORMATS``;
* :mod:`.write`  -- :func:`save_mesh` and the exact PLY / OBJ / OFF / VRML writers (with per-vertex
  colours; a textured mesh as OBJ + MTL + PNG);
* :mod:`.obj`    -- the Wavefront OBJ reader (vertex colours, texture coordinates, materials);
* :mod:`.vrml`   -- the VRML 2.0 parser :func:`read_wrl` (raw V (N, 3), F (M, 3), file units; colour
  and texture with :func:`~.vrml.read_wrl_with_appearance`);
* :mod:`.appearance` -- a file's colour as the readers find it, texture images and MTL files;
* :mod:`.bnd`    -- :func:`load_bnd`, BU-3DFE ``.bnd`` landmark files;
* :mod:`.atomic` -- atomic writes (:func:`~.atomic.atomic_path`, ``write_bytes_atomic``,
  ``write_json``): a result file is complete or absent.

Layer rule: io imports only facecorr.errors, facecorr.names, facecorr.geometry and itself.
"""

from __future__ import annotations

from .bnd import load_bnd
from .load import MESH_FORMATS, UNIT_TO_MM, infer_units, load_mesh
from .vrml import read_wrl
from .write import save_mesh

__all__ = [
    "MESH_FORMATS",
    "UNIT_TO_MM",
    "infer_units",
    "load_mesh",
    "save_mesh",
    "load_bnd",
    "read_wrl",
]
