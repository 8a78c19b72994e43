"""Loading face scans: format dispatch, validation/cleaning and unit inference.

* OBJ, PLY, STL, OFF, GLB are read through trimesh with ``process=False`` (and ``maintain_order``
  for OBJ), so the file's vertex order is kept; every trimesh failure is translated into a
  one-line :class:`~facecorr.errors.MeshFileError`. Broken binary STL and truncated OFF files,
  which trimesh reads silently, are checked first.
* VRML 2.0 (``.wrl``/``.vrml``, e.g. BU-3DFE) is read by :func:`facecorr.io.vrml.read_wrl`.

Validation on load (:func:`load_mesh`), in this order, with the counts in ``mesh.meta``:

1. no vertices -> MeshError "empty"; vertices but no faces -> MeshError "point cloud";
   NaN/inf coordinates -> MeshError; face indices out of range -> MeshError;
2. exact duplicate vertices are merged (first occurrence kept, order otherwise unchanged;
   ``meta["n_duplicate_vertices_merged"]``);
3. degenerate faces (a repeated vertex, or area <= 1e-12 x bbox-diagonal²) are dropped
   (``meta["n_degenerate_faces_dropped"]``); if none is left -> MeshError; then repeated
   triangles (same three vertices) are dropped (``meta["n_duplicate_faces_dropped"]``);
4. connected pieces are kept; ``meta["n_components"]`` counts the pieces with faces (the largest
   by area, ``mesh.largest_component()``, is the face unless told otherwise);
5. units (see :func:`infer_units`, applied to the largest piece) -> ``mesh.to_mm``, ``mesh.units``.

``format_of``, ``unit_factor`` and ``one_line`` are shared with :mod:`facecorr.io.write`.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshFileError, UnitsError
from ..geometry.mesh import Mesh
from .vrml import read_wrl

__all__ = ["MESH_FORMATS", "UNIT_TO_MM", "infer_units", "load_mesh"]

#: Factor from each unit to millimetres.
UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}

_TRIMESH_FORMATS = {".obj": "obj", ".ply": "ply", ".stl": "stl", ".off": "off", ".glb": "glb"}
_WRL_FORMATS = {".wrl": "wrl", ".vrml": "wrl"}
#: Extensions load_mesh / save_mesh understand.
MESH_FORMATS = tuple(sorted({**_TRIMESH_FORMATS, **_WRL_FORMATS}))

# Plausible largest bounding-box side of a face or head scan, per unit (source units):
# metres 0.03-1, centimetres 3-60, millimetres 60-1000. Sizes in the gaps are refused.
_AUTO_UNIT_RANGES = (("m", 0.03, 1.0), ("cm", 3.0, 60.0), ("mm", 60.0, 1000.0))


def infer_units(vertices: np.ndarray) -> str:
    """Units of a face/head scan from the largest side ``s`` of its bounding box.

    A face or head is 6 cm to 1 m across (a cropped nose region to a head with shoulders):
    ``0.03 <= s <= 1`` -> "m", ``3 <= s < 60`` -> "cm", ``60 <= s <= 1000`` -> "mm". Anything else
    (including 1 < s < 3) is not a plausible face in any unit: :class:`UnitsError`, pass ``units``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    s = float((v.max(axis=0) - v.min(axis=0)).max()) if len(v) else 0.0
    for unit, lo, hi in _AUTO_UNIT_RANGES:
        if lo <= s <= hi and not (unit == "cm" and s == hi):
            return unit
    raise UnitsError(
        f"cannot infer units: largest bounding-box side is {s:.4g}, not a face in m (0.03-1), "
        f"cm (3-60) or mm (60-1000); pass units='mm', 'cm' or 'm'"
    )


def unit_factor(units: str) -> float:
    """Millimetres per unit of ``units`` ("mm", "cm" or "m"); anything else -> UnitsError."""
    try:
        return UNIT_TO_MM[units]
    except (KeyError, TypeError):
        raise UnitsError(f"unknown units {units!r}; use 'mm', 'cm', 'm' (or 'auto' to load)") from None


def format_of(path: Path) -> str:
    """Format name ("obj", "ply", "stl", "off", "glb" or "wrl") from the extension of ``path``;
    an unknown extension -> MeshFileError."""
    ext = path.suffix.lower()
    if ext in _TRIMESH_FORMATS:
        return _TRIMESH_FORMATS[ext]
    if ext in _WRL_FORMATS:
        return "wrl"
    raise MeshFileError(
        f"{path}: unknown mesh format {ext or '(no extension)'!r} (supported: {', '.join(MESH_FORMATS)})"
    )


def _check_readable(path: Path) -> None:
    """MeshFileError unless ``path`` is an existing, readable, non-empty regular file."""
    if not path.exists():
        raise MeshFileError(f"{path}: no such file")
    if path.is_dir():
        raise MeshFileError(f"{path}: is a directory, not a mesh file")
    try:
        with open(path, "rb") as fh:
            fh.read(1)
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    if path.stat().st_size == 0:
        raise MeshFileError(f"{path}: the file is empty (0 bytes)")


def one_line(e: BaseException) -> str:
    """``Type: first line of the message`` of an exception from a third-party reader/writer."""
    msg = str(e).strip().splitlines()
    return f"{type(e).__name__}: {msg[0]}" if msg else type(e).__name__


def _read_trimesh(path: Path, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw (V, F) via trimesh; F is (M, 3) or empty. Any trimesh failure -> MeshFileError."""
    import trimesh

    if fmt == "stl":
        _check_binary_stl(path)
    elif fmt == "off":
        _check_off(path)
    try:
        with warnings.catch_warnings():  # trimesh warns about textures/colours we ignore
            warnings.simplefilter("ignore")
            geom = trimesh.load(str(path), file_type=fmt, process=False, maintain_order=True,
                                skip_materials=True)
        parts = geom.dump() if isinstance(geom, trimesh.Scene) else [geom]
        Vs, Fs, off = [], [], 0
        for g in parts:
            v = np.asarray(getattr(g, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
            f = np.asarray(getattr(g, "faces", np.zeros((0, 3))), dtype=np.int64)
            f = f.reshape(-1, 3) if f.size else np.zeros((0, 3), np.int64)
            Vs.append(v)
            Fs.append(f + off)
            off += len(v)
    except (MeshError, MeshFileError):
        raise
    except IndexError as e:  # trimesh indexing vertices with a face index that is out of range
        raise MeshError(f"{path}: face indices out of range ({one_line(e)})") from None
    except Exception as e:  # noqa: BLE001 - trimesh raises anything on broken files
        raise MeshFileError(f"{path}: cannot read {fmt.upper()} file ({one_line(e)})") from None
    V = np.concatenate(Vs) if Vs else np.zeros((0, 3))
    F = np.concatenate(Fs) if Fs else np.zeros((0, 3), np.int64)
    return V, F


def _check_binary_stl(path: Path) -> None:
    """A binary STL (not starting with 'solid') must be 84 + 50 x (triangle count) bytes long."""
    with open(path, "rb") as fh:
        head = fh.read(84)
    if head[:5].lower() == b"solid" and b"facet" in path.read_bytes()[:4096]:
        return  # ASCII STL: trimesh parses and checks it
    size = path.stat().st_size
    if len(head) < 84:
        raise MeshFileError(f"{path}: broken binary STL ({size} bytes, shorter than its 84-byte header)")
    n = int(np.frombuffer(head[80:84], "<u4")[0])
    if size != 84 + 50 * n:
        raise MeshFileError(f"{path}: broken binary STL (header says {n} triangles = {84 + 50 * n} bytes, "
                            f"file has {size})")


def _check_off(path: Path) -> None:
    """OFF: the vertex and face counts of the header must be present, face indices in range
    (trimesh silently reads a truncated face list)."""
    try:
        lines = [ln.split("#", 1)[0].split() for ln in path.read_text(errors="replace").splitlines()]
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    lines = [ln for ln in lines if ln]
    if not lines or not lines[0][0].upper().endswith("OFF"):
        raise MeshFileError(f"{path}: broken OFF file (no 'OFF' header)")
    head = lines[0][1:] or (lines[1] if len(lines) > 1 else [])
    body = lines[1:] if lines[0][1:] else lines[2:]
    try:
        nv, nf = int(head[0]), int(head[1])
    except (IndexError, ValueError):
        raise MeshFileError(f"{path}: broken OFF file (no vertex/face counts)") from None
    if nv < 0 or nf < 0 or len(body) < nv + nf:
        raise MeshFileError(f"{path}: broken OFF file (header says {nv} vertices and {nf} faces, "
                            f"found {len(body)} lines): truncated?")
    for k, ln in enumerate(body[nv:nv + nf]):
        try:
            n = int(ln[0])
            idx = [int(x) for x in ln[1:1 + n]]
        except ValueError:
            raise MeshFileError(f"{path}: broken OFF file (face {k} is not integers)") from None
        if len(idx) < n:
            raise MeshFileError(f"{path}: broken OFF file (face {k} has {len(idx)} of {n} indices)")
        if idx and (min(idx) < 0 or max(idx) >= nv):
            raise MeshError(f"{path}: face {k} has vertex indices {idx} outside [0, {nv - 1}]")


def _merge_duplicates(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Merge exactly equal vertices, keeping first occurrences in their original order."""
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    n_dup = len(V) - len(first)
    if n_dup == 0:
        return V, F, 0
    keep = np.sort(first)  # kept vertices in file order
    new_of_unique = np.empty(len(first), np.int64)
    new_of_unique[np.argsort(first)] = np.arange(len(first))  # unique group -> new id
    remap = new_of_unique[inverse]
    return V[keep], remap[F], n_dup


def _clean(V, F, name: str, merge_duplicates: bool) -> tuple[np.ndarray, np.ndarray, dict]:
    """Validate raw (V (N, 3), F (M, 3)) in file units and clean them (steps 1-3 of the module
    docstring): returns (V (N', 3) float64, F (M', 3) int64, meta counts). ``name`` is for messages.
    """
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    if len(V) == 0:
        raise MeshError(f"{name}: the mesh is empty (no vertices)")
    if len(F) == 0:
        raise MeshError(f"{name}: a point cloud without faces ({len(V)} vertices); a triangle mesh is needed")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise MeshError(f"{name}: {int(bad.sum())} vertices have NaN or infinite coordinates "
                        f"(first: vertex {int(np.argmax(bad))})")
    if F.min() < 0 or F.max() >= len(V):
        k = int(np.argmax((F < 0).any(axis=1) | (F >= len(V)).any(axis=1)))
        raise MeshError(f"{name}: face {k} has vertex indices {F[k].tolist()} outside [0, {len(V) - 1}]")
    meta = {"n_vertices_in_file": int(len(V)), "n_faces_in_file": int(len(F))}
    n_dup = 0
    if merge_duplicates:
        V, F, n_dup = _merge_duplicates(V, F)
    meta["n_duplicate_vertices_merged"] = int(n_dup)
    a, b, c = (V[F[:, k]] for k in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    degenerate = repeated | (area2 <= 2e-12 * diag * diag)
    meta["n_degenerate_faces_dropped"] = int(degenerate.sum())
    F = F[~degenerate]
    if len(F) == 0:
        raise MeshError(f"{name}: all {len(degenerate)} faces are degenerate (zero area)")
    # the same triangle twice (any rotation or orientation): keep the first
    _, first = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
    meta["n_duplicate_faces_dropped"] = int(len(F) - len(first))
    F = F[np.sort(first)]
    return V, F, meta


def load_mesh(path, units: str = "auto", *, merge_duplicates: bool = True) -> Mesh:
    """Load and validate a triangle mesh, converting it to millimetres.

    Parameters
    ----------
    path : str or Path
        ``.obj``, ``.ply``, ``.stl``, ``.off``, ``.glb`` (trimesh) or ``.wrl``/``.vrml``
        (VRML 2.0 IndexedFaceSet, e.g. BU-3DFE).
    units : "auto", "mm", "cm" or "m"
        Units of the file's coordinates; "auto" infers them from the bounding box
        (:func:`infer_units`).
    merge_duplicates : bool
        Merge exactly coincident vertices (STL always needs it; the count is in ``meta``).

    Returns
    -------
    Mesh
        Vertices (N, 3) in mm, faces (M, 3); ``to_mm`` and ``units`` remember the file's units;
        ``meta`` holds ``format``, ``n_vertices_in_file``, ``n_faces_in_file``,
        ``n_duplicate_vertices_merged``, ``n_degenerate_faces_dropped``,
        ``n_duplicate_faces_dropped``, ``n_components``,
        ``units_inferred``.

    Raises
    ------
    MeshFileError
        Missing, unreadable, unknown-format, broken or truncated file.
    MeshError
        Empty mesh, point cloud, NaN/inf coordinates, out-of-range indices, only degenerate faces.
    UnitsError
        Unknown ``units``, or "auto" cannot place the size as a face in m, cm or mm.
    """
    path = Path(path)
    if units != "auto":
        factor = unit_factor(units)
    fmt = format_of(path)
    _check_readable(path)
    if fmt == "wrl":
        V, F = read_wrl(path)
    else:
        V, F = _read_trimesh(path, fmt)
    V, F, meta = _clean(V, F, str(path), merge_duplicates)
    # Components in the file's units (labels do not depend on the scale).
    labels = Mesh(V, F, source=str(path)).components
    meta["n_components"] = int(len(np.unique(labels[F[:, 0]])))
    inferred = units == "auto"
    if inferred:  # by the largest piece, so that far-away debris does not change the size
        units = infer_units(V[labels == 0])
        factor = UNIT_TO_MM[units]
    meta.update(format=fmt, units_inferred=inferred)
    mesh = Mesh(V * factor, F, to_mm=factor, units=units, source=str(path), meta=meta)
    mesh.__dict__["components"] = labels  # seed the cached property
    return mesh

