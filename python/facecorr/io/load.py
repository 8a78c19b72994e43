"""Loading face scans: format dispatch, validation/cleaning and unit inference.

* OBJ and OFF are read by our own readers (:func:`facecorr.io.obj.read_obj`, :func:`_read_off`:
  file order kept, OBJ relative indices, CRLF, a UTF-8 BOM and non-UTF-8 bytes in comments
  handled, non-integer face indices refused).
* PLY in its common layouts is read by a Rust fast path (:func:`_read_ply`); other PLY files,
  STL and GLB are read through trimesh with ``process=False``, so the file's vertex order is
  kept; every trimesh failure is translated into a one-line :class:`~facecorr.errors.MeshFileError`.
  Broken binary STL files, which trimesh reads silently, are checked first.
* Files that are really gzip/zip/PNG/JPEG/... (a misnamed download) are refused by name.
* VRML 2.0 (``.wrl``/``.vrml``, e.g. BU-3DFE) is read by :func:`facecorr.io.vrml.read_wrl`.

Colour is kept when the file has it (``mesh.vertex_colors``, or ``mesh.face_uv`` +
``mesh.texture``; ``meta["colour"]`` = "vertex", "texture" or None): PLY / GLB vertex colours or
texture (trimesh; a PLY names its image in a ``comment TextureFile`` line), OBJ ``v x y z r g b``
or ``vt`` + ``mtllib``/``map_Kd`` (:mod:`.obj`), VRML ``Color`` or ``ImageTexture`` +
``TextureCoordinate`` (:mod:`.vrml`). Colour a file declares but that cannot be used is dropped
with the reason in ``meta["colour_note"]`` (:mod:`.appearance`); OFF and STL colours are not read.
The cleaning steps below renumber the colour with the vertices and triangles they keep.

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

import logging
import warnings
from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshFileError, UnitsError
from ..geometry.mesh import Mesh
from .appearance import Appearance, read_image
from .obj import read_obj, read_text
from .vrml import read_wrl_with_appearance

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

    Vertices farther from the median than 3x the 90th-percentile distance are left out (a spike
    must not change the units). A face or head is 6 cm to 1 m across (a cropped nose region to a head with shoulders):
    ``0.03 <= s <= 1`` -> "m", ``3 <= s < 60`` -> "cm", ``60 <= s <= 1000`` -> "mm". Anything else
    (including 1 < s < 3) is not a plausible face in any unit: :class:`UnitsError`, pass ``units``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if len(v):
        # stray points (a spike, a speck far away) do not make a face bigger: keep the vertices
        # within 3x the 90th-percentile distance from the median
        r = np.linalg.norm(v - np.median(v, axis=0), axis=1)
        v = v[r <= 3.0 * np.percentile(r, 90)]
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


def _read_trimesh(path: Path, fmt: str) -> tuple[np.ndarray, np.ndarray, Appearance]:
    """Raw (V, F, appearance) via trimesh; F is (M, 3) or empty. Any trimesh failure -> MeshFileError."""
    import trimesh

    if fmt == "stl":
        _check_binary_stl(path)
    elif fmt == "ply":
        _check_ply(path)
    logs = [logging.getLogger(n) for n in ("trimesh", *logging.root.manager.loggerDict) if n.startswith("trimesh")]
    quiet = [lg.disabled for lg in logs]
    try:
        with warnings.catch_warnings():  # trimesh warns (and logs tracebacks) about textures it cannot read
            warnings.simplefilter("ignore")
            for lg in logs:
                lg.disabled = True
            try:
                geom = trimesh.load(str(path), file_type=fmt, process=False, maintain_order=True,
                                    skip_materials=fmt == "stl")
            finally:
                for lg, q in zip(logs, quiet):
                    lg.disabled = q
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
    return V, F, _trimesh_appearance(parts, Fs, path, fmt)


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray, Appearance]:
    """Raw (V, F, appearance) of a PLY. The common layouts (binary either byte order or ASCII; a
    vertex element with x y z, optional uchar colours; a face element of triangles or quads) are
    read by the Rust fast path (:func:`facecorr._core.read_ply`: a command reading a PLY no
    longer imports trimesh, and with it scipy; the read itself is ~2x faster); anything else,
    broken files included, by trimesh exactly as before (so the same mesh, and the same error)."""
    from .. import _core

    _check_ply(path)
    fast = _core.read_ply(str(path))
    if fast is None:
        return _read_trimesh(path, "ply")
    V, F, colours = fast
    app = Appearance()
    if colours is not None:
        app.vertex_colors = colours[:, :3].astype(np.float64) / 255.0
    return V, F, app


def _ply_texture_file(path: Path) -> Path | None:
    """The image a PLY names in its header (``comment TextureFile NAME``, MeshLab's convention),
    relative to the PLY's folder; None if it names none."""
    with open(path, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    for line in head[:max(end, 0)].decode("latin-1").splitlines():
        w = line.split(None, 2)
        if len(w) == 3 and w[0] == "comment" and w[1].lower() == "texturefile":
            return path.parent / w[2].strip()
    return None


def _trimesh_appearance(parts: list, faces: list, path: Path, fmt: str) -> Appearance:
    """The colour of trimesh geometries: vertex colours when every part has them, a texture when
    there is one part with texture coordinates and an image (a PLY's ``TextureFile``, read by us:
    trimesh substitutes a blank image for a missing one; a GLB's embedded base colour texture);
    anything else -> a note."""
    app = Appearance()
    kinds = [getattr(getattr(g, "visual", None), "kind", None) for g in parts]
    try:
        if kinds and all(k == "vertex" for k in kinds):
            cols = [np.asarray(g.visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0 for g in parts]
            app.vertex_colors = np.concatenate(cols).reshape(-1, 3)
        elif kinds == ["texture"]:
            uv = np.asarray(parts[0].visual.uv, dtype=np.float64)
            img, why = None, "texture coordinates but no texture image"
            if fmt == "ply":
                name = _ply_texture_file(path)
                try:
                    img = read_image(name) if name is not None else None
                except ValueError as e:
                    why = str(e)
            else:
                img = _material_image(getattr(parts[0].visual, "material", None))
            if img is None:
                app.add_note(f"{why}: texture not used")
            elif uv.shape != (len(parts[0].vertices), 2) or not np.isfinite(uv).all():
                app.add_note("broken texture coordinates: texture not used")
            else:
                app.corner_uv, app.texture = uv[faces[0]], img
        elif "face" in kinds:
            app.add_note("per-face colours are not supported (only per-vertex colours or a texture)")
        elif any(k in ("vertex", "texture") for k in kinds):
            app.add_note(f"colour on {sum(k in ('vertex', 'texture') for k in kinds)} of {len(kinds)} "
                         "parts, or several textured parts: colour not used")
    except Exception as e:  # noqa: BLE001 - colour must never make a readable mesh unreadable
        app = Appearance(note=f"colour not readable ({one_line(e)})")
    return app


def _material_image(material) -> np.ndarray | None:
    """(H, W, 3) uint8 of a trimesh material's colour image (SimpleMaterial ``image``, glTF
    ``baseColorTexture``), None if it has none."""
    img = getattr(material, "baseColorTexture", None)
    if img is None and type(material).__name__ != "PBRMaterial":
        img = getattr(material, "image", None)
    if img is None:
        return None
    arr = np.asarray(img.convert("RGB") if hasattr(img, "convert") else img)
    return np.ascontiguousarray(arr[:, :, :3] if arr.ndim == 3 else np.repeat(arr[:, :, None], 3, axis=2),
                                dtype=np.uint8)


def _check_ply(path: Path) -> None:
    """PLY header sanity (trimesh reads a short ASCII body silently): the header must end, element
    counts be integers, and an ASCII body have at least one line per element row."""
    with open(path, "rb") as fh:
        head = fh.read(65536)
    if not head.startswith(b"ply"):
        return  # trimesh reports 'not a ply file'
    end = head.find(b"end_header")
    if end < 0:
        raise MeshFileError(f"{path}: broken PLY file (no 'end_header' in the first 64 KiB)")
    words = [ln.split() for ln in head[:end].decode("latin-1").splitlines()]
    fmt = next((w[1] for w in words if len(w) > 1 and w[0] == "format"), None)
    total = 0
    for w in words:
        if w and w[0] == "element":
            try:
                total += int(w[2])
                if int(w[2]) < 0:
                    raise ValueError
            except (IndexError, ValueError):
                raise MeshFileError(f"{path}: broken PLY header ({' '.join(w)[:60]!r})") from None
    if fmt == "ascii":
        body = path.read_bytes()[end:].split(b"\n", 1)
        rows = sum(1 for ln in body[1].splitlines() if ln.strip()) if len(body) > 1 else 0
        if rows < total:
            raise MeshFileError(f"{path}: broken PLY file (the header declares {total} element rows, "
                                f"the body has {rows} lines): truncated?")


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


# Binary signatures of files that are often misnamed (a compressed download, an image, an archive).
_SIGNATURES = (
    (b"\x1f\x8b", "gzip-compressed data (decompress it first)"),
    (b"PK\x03\x04", "a ZIP archive (extract it first)"),
    (b"BZh", "bzip2-compressed data (decompress it first)"),
    (b"\xfd7zXZ\x00", "xz-compressed data (decompress it first)"),
    (b"7z\xbc\xaf\x27\x1c", "a 7-Zip archive (extract it first)"),
    (b"\x28\xb5\x2f\xfd", "zstd-compressed data (decompress it first)"),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF8", "a GIF image"),
    (b"BM", None),  # BMP: only with a plausible header (checked below); "BM" may start text
    (b"%PDF", "a PDF document"),
)


def _a(fmt: str) -> str:
    """'an OBJ', 'a PLY': the format name with its article."""
    return f"{'an' if fmt.upper()[0] in 'AEFHILMNORSX' else 'a'} {fmt.upper()}"


def _sniff(path: Path, fmt: str) -> None:
    """MeshFileError if the file starts with the signature of a well-known non-mesh format."""
    with open(path, "rb") as fh:
        head = fh.read(16)
    for magic, what in _SIGNATURES:
        if fmt == "wrl" and magic == b"\x1f\x8b":
            continue  # gzip-compressed VRML is valid (read_wrl decompresses it)
        if head.startswith(magic):
            if what is None:  # BMP: 'BM', then the file size (little-endian) in bytes 2-6
                if len(head) < 6 or int.from_bytes(head[2:6], "little") != path.stat().st_size:
                    continue
                what = "a BMP image"
            raise MeshFileError(f"{path}: the file is {what}, not {_a(fmt)} mesh")


_OFF_HEADERS = {"OFF", "COFF", "NOFF", "CNOFF", "STOFF", "STCOFF", "STNOFF", "STCNOFF"}


def _read_off(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Raw (V, F) of an ASCII OFF file (header ``[ST][C][N]OFF``, counts ``nv nf ne``, then one
    vertex and one face per line, ``#`` comments and blank lines skipped). Extra values on a line
    (normals, colours) are ignored; polygons are fan-triangulated. Missing counts, a truncated file,
    non-integer face indices -> MeshFileError; indices out of range -> MeshError."""
    text = read_text(path, "off")
    lines = [(n, ln.split("#", 1)[0].split()) for n, ln in enumerate(text.splitlines(), 1)]
    lines = [x for x in lines if x[1]]
    if not lines or not lines[0][1][0].upper().endswith("OFF"):
        raise MeshFileError(f"{path}: broken OFF file (no 'OFF' header)")
    kw = lines[0][1][0].upper()
    if kw not in _OFF_HEADERS:
        raise MeshFileError(f"{path}: unsupported OFF variant {lines[0][1][0][:20]!r} (only 3D "
                            f"OFF/COFF/NOFF/STOFF)")
    if len(lines[0][1]) > 1 and lines[0][1][1].upper() == "BINARY":
        raise MeshFileError(f"{path}: binary OFF is not supported")
    head = lines[0][1][1:] or (lines[1][1] if len(lines) > 1 else [])
    body = lines[1:] if lines[0][1][1:] else lines[2:]
    try:
        nv, nf = int(head[0]), int(head[1])
    except (IndexError, ValueError):
        raise MeshFileError(f"{path}: broken OFF file (no vertex/face counts)") from None
    if nv < 0 or nf < 0 or len(body) < nv + nf:
        raise MeshFileError(f"{path}: broken OFF file (header says {nv} vertices and {nf} faces, "
                            f"found {len(body)} lines): truncated?")
    vb, fb = body[:nv], body[nv:nv + nf]
    if all(len(ln) == 3 for _, ln in vb) and all(len(ln) == 4 and ln[0] == "3" for _, ln in fb):
        try:  # the common all-triangle file, in two numpy calls
            V = np.array([ln for _, ln in vb], dtype=object).reshape(-1, 3).astype(np.float64)
            F = np.array([ln[1:] for _, ln in fb], dtype=object).reshape(-1, 3).astype(np.int64)
        except (ValueError, OverflowError):
            pass  # the loops below name the broken line
        else:
            if not F.size or (F.min() >= 0 and F.max() < nv):
                return V, F
    V = np.empty((nv, 3), np.float64)
    for k, (n, ln) in enumerate(vb):
        try:
            V[k] = [float(x) for x in ln[:3]]
        except ValueError:
            raise MeshFileError(f"{path}: broken OFF at line {n}: vertex {k} is not 3 numbers") from None
    tris: list = []
    for k, (n, ln) in enumerate(fb):
        try:
            m = int(ln[0])
            idx = [int(x) for x in ln[1:1 + m]]
        except ValueError:
            raise MeshFileError(f"{path}: broken OFF at line {n}: face {k} is not integers") from None
        if m < 0 or len(idx) < m:
            raise MeshFileError(f"{path}: broken OFF at line {n}: face {k} has {len(idx)} of "
                                f"{m} indices")
        if idx and (min(idx) < 0 or max(idx) >= nv):
            raise MeshError(f"{path}: face {k} has vertex indices {idx[:8]} outside [0, {nv - 1}]")
        if m >= 3:
            tris.extend((idx[0], idx[j], idx[j + 1]) for j in range(1, m - 1))
        elif m:
            tris.append((idx[0], idx[-1], idx[-1]))
    return V, np.array(tris, np.int64).reshape(-1, 3)


#: Largest scan accepted. Peak memory is ~0.65 GB per million vertices (BENCHMARKS.md, "Huge
#: scans"), so this is ~13 GB; the registration gains nothing from more than ~1 mm sampling.
MAX_VERTICES = 20_000_000

#: Largest coordinate accepted (1e9 km in mm): beyond it areas and distances overflow float64.
_MAX_COORD = 1e15


def _equal_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, group) of the rows of ``a`` (N, 3) float64 or int64: ``first`` (G,) the index of
    each group of equal rows' first occurrence, in file order, and ``group`` (N,) each row's group
    (an index into ``first``). Hashed in Rust (``_core.equal_rows``): on a 56k-vertex scan 5-10x
    faster than the lexsort it replaces (the reference in ``tests/test_io.py``)."""
    from .. import _core

    return _core.equal_rows(np.ascontiguousarray(a))


def _merge_duplicates(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge exactly equal vertices, keeping first occurrences in their original order: (V', F',
    kept) with ``kept`` the original ids of the vertices of V'."""
    first, group = _equal_rows(V)
    if len(first) == len(V):
        return V, F, np.arange(len(V))
    # groups are numbered in file order of their first vertex: a group's number is its new id
    return V[first], group[F], first


def _clean(V, F, name: str, merge_duplicates: bool):
    """Validate raw (V (N, 3), F (M, 3)) in file units and clean them (steps 1-3 of the module
    docstring): returns (V (N', 3) float64, F (M', 3) int64, meta counts, vertex_ids (N',),
    face_ids (M',)), the last two the raw ids of the rows kept (to renumber the colour). ``name``
    is for messages.
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
    big = (np.abs(V) > _MAX_COORD).any(axis=1)
    if big.any():
        raise MeshError(f"{name}: {int(big.sum())} vertices have coordinates beyond ±{_MAX_COORD:.0e} "
                        f"(first: vertex {int(np.argmax(big))}: {V[int(np.argmax(big))].tolist()}); "
                        f"not a face scan in any unit")
    if F.min() < 0 or F.max() >= len(V):
        k = int(np.argmax((F < 0).any(axis=1) | (F >= len(V)).any(axis=1)))
        raise MeshError(f"{name}: face {k} has vertex indices {F[k].tolist()} outside [0, {len(V) - 1}]")
    if len(V) > MAX_VERTICES:
        raise MeshError(f"{name}: {len(V):,} vertices, more than facecorr takes ({MAX_VERTICES:,}; memory grows "
                        f"~0.65 GB per million vertices): decimate the scan first")
    meta = {"n_vertices_in_file": int(len(V)), "n_faces_in_file": int(len(F))}
    vertex_ids = np.arange(len(V))
    if merge_duplicates:
        V, F, vertex_ids = _merge_duplicates(V, F)
    meta["n_duplicate_vertices_merged"] = int(meta["n_vertices_in_file"] - len(V))
    # twice the triangle areas, |(b - a) × (c - a)| (the Rust kernel: 5x numpy's gather + cross;
    # |V| <= 1e15: no overflow, tiny areas may underflow to 0)
    from .. import _core

    area2 = 2.0 * _core.mesh_face_areas(V, F)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    degenerate = repeated | (area2 <= 2e-12 * diag * diag)
    meta["n_degenerate_faces_dropped"] = int(degenerate.sum())
    face_ids = np.flatnonzero(~degenerate)
    F = F[face_ids]
    if len(F) == 0:
        raise MeshError(f"{name}: all {len(degenerate)} faces are degenerate (zero area)")
    # the same triangle twice (any rotation or orientation): keep the first
    first, _ = _equal_rows(np.sort(F, axis=1))  # first occurrences, in file order
    meta["n_duplicate_faces_dropped"] = int(len(F) - len(first))
    return V, F[first], meta, vertex_ids, face_ids[first]


def _colour_fields(app: Appearance, n_raw: int, m_raw: int, vertex_ids, face_ids, meta: dict) -> dict:
    """Mesh keyword arguments for the colour of ``app`` (raw-indexed) renumbered to the cleaned
    mesh; ``meta["colour"]`` / ``meta["colour_note"]`` record what was kept and why not."""
    out = {}
    if app.vertex_colors is not None:
        c = np.asarray(app.vertex_colors, dtype=np.float64)
        if c.shape == (n_raw, 3) and np.isfinite(c).all() and c.min() >= 0.0 and c.max() <= 1.0:
            out["vertex_colors"] = c[vertex_ids]
        else:
            app.add_note("broken vertex colours: not used")
    if app.corner_uv is not None:
        uv = np.asarray(app.corner_uv, dtype=np.float64)
        img = app.texture
        if uv.shape == (m_raw, 3, 2) and np.isfinite(uv).all() and img is not None and img.ndim == 3:
            out["face_uv"], out["texture"] = uv[face_ids], img
        else:
            app.add_note("broken texture coordinates: texture not used")
    meta["colour"] = "texture" if "face_uv" in out else ("vertex" if out else None)
    if app.note:
        meta["colour_note"] = app.note
    return out


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
        ``units_inferred``, ``colour`` ("vertex", "texture" or None) and, when colour in the file
        was not used, ``colour_note``. A coloured scan has ``vertex_colors`` or ``face_uv`` +
        ``texture`` (module docstring).

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
    if fmt != "stl":  # a binary STL header is free text; its size check catches other files
        _sniff(path, fmt)
    if fmt == "wrl":
        V, F, app = read_wrl_with_appearance(path)
    elif fmt == "obj":
        V, F, app = read_obj(path)
    elif fmt == "off":
        V, F = _read_off(path)
        app = Appearance()
    elif fmt == "ply":
        V, F, app = _read_ply(path)
    else:
        V, F, app = _read_trimesh(path, fmt)
    n_raw, m_raw = len(V), len(F)
    V, F, meta, vertex_ids, face_ids = _clean(V, F, str(path), merge_duplicates)
    colour = _colour_fields(app, n_raw, m_raw, vertex_ids, face_ids, meta)
    # Components in the file's units (labels do not depend on the scale).
    labels = Mesh(V, F, source=str(path)).components
    meta["n_components"] = int(np.count_nonzero(np.bincount(labels[F[:, 0]])))  # pieces with a face
    inferred = units == "auto"
    if inferred:  # by the largest piece, so that far-away debris does not change the size
        try:
            units = infer_units(V[labels == 0])
        except UnitsError as e:
            raise UnitsError(f"{path}: {e}") from None
        factor = UNIT_TO_MM[units]
    meta.update(format=fmt, units_inferred=inferred)
    mesh = Mesh(V * factor, F, to_mm=factor, units=units, source=str(path), meta=meta, **colour)
    mesh.__dict__["components"] = labels  # seed the cached property
    return mesh

