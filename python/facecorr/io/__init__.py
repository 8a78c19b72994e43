"""Reading and writing face scans: meshes (OBJ, PLY, STL, OFF, GLB, VRML 2.0) and BU-3DFE landmarks.

* OBJ, PLY, STL, OFF, GLB are read through trimesh with ``process=False`` (and ``maintain_order``
  for OBJ), so the file's vertex order is kept; every trimesh failure is translated into a
  one-line :class:`~facecorr.errors.MeshFileError`.
* VRML 2.0 (``.wrl``/``.vrml``, e.g. BU-3DFE) and BU-3DFE ``.bnd`` landmark files use the small
  parsers below: every ``IndexedFaceSet`` reached through ``children`` / ``Shape.geometry`` is read
  (``coord Coordinate { point [...] }`` or ``USE``, ``coordIndex [... -1 ...]`` polygons,
  fan-triangulated; ``ccw FALSE`` flips them); several shapes are merged; ``Transform`` nodes are
  applied; texture, normal and colour nodes are ignored.

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
"""

from __future__ import annotations

import math
import os
import re
import secrets
import warnings
from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshFileError, UnitsError
from ..geometry import transforms
from ..geometry.mesh import Mesh

__all__ = [
    "MESH_FORMATS",
    "UNIT_TO_MM",
    "infer_units",
    "load_mesh",
    "save_mesh",
    "load_bnd",
    "read_wrl",
    "write_wrl",
]

#: Factor from each unit to millimetres.
UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}

_TRIMESH_FORMATS = {".obj": "obj", ".ply": "ply", ".stl": "stl", ".off": "off", ".glb": "glb"}
_WRL_FORMATS = {".wrl": "wrl", ".vrml": "wrl"}
#: Extensions load_mesh / save_mesh understand.
MESH_FORMATS = tuple(sorted({**_TRIMESH_FORMATS, **_WRL_FORMATS}))

# Plausible largest bounding-box side of a face or head scan, per unit (source units):
# metres 0.03-1, centimetres 3-60, millimetres 60-1000. Sizes in the gaps are refused.
_AUTO_UNIT_RANGES = (("m", 0.03, 1.0), ("cm", 3.0, 60.0), ("mm", 60.0, 1000.0))


# ----------------------------------------------------------------------------- units


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


def _unit_factor(units: str) -> float:
    try:
        return UNIT_TO_MM[units]
    except (KeyError, TypeError):
        raise UnitsError(f"unknown units {units!r}; use 'mm', 'cm', 'm' (or 'auto' to load)") from None


# ----------------------------------------------------------------------------- load


def _format_of(path: Path) -> str:
    ext = path.suffix.lower()
    if ext in _TRIMESH_FORMATS:
        return _TRIMESH_FORMATS[ext]
    if ext in _WRL_FORMATS:
        return "wrl"
    raise MeshFileError(
        f"{path}: unknown mesh format {ext or '(no extension)'!r} (supported: {', '.join(MESH_FORMATS)})"
    )


def _check_readable(path: Path) -> None:
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


def _one_line(e: BaseException) -> str:
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
        raise MeshError(f"{path}: face indices out of range ({_one_line(e)})") from None
    except Exception as e:  # noqa: BLE001 - trimesh raises anything on broken files
        raise MeshFileError(f"{path}: cannot read {fmt.upper()} file ({_one_line(e)})") from None
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
        factor = _unit_factor(units)
    fmt = _format_of(path)
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


# ----------------------------------------------------------------------------- save


def _atomic_write(path: Path, data: bytes) -> None:
    """Write to a temporary file beside ``path`` and rename: no partial output on failure.
    (Created with ``open(..., "xb")`` so the file gets the usual umask permissions.)"""
    if not path.parent.exists():
        raise MeshFileError(f"{path}: directory {path.parent} does not exist")
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    try:
        with open(tmp, "xb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except OSError as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise MeshFileError(f"{path}: cannot write: {e.strerror or e}") from None


def _ply_bytes(V: np.ndarray, F: np.ndarray) -> bytes:
    """Binary little-endian PLY with float64 vertices (exact) and int32 triangle indices."""
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by facecorr\n"
              f"element vertex {len(V)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    faces = np.empty(len(F), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    faces["n"] = 3
    faces["idx"] = F
    return header.encode("ascii") + np.ascontiguousarray(V, "<f8").tobytes() + faces.tobytes()


def _xyz_lines(V: np.ndarray, prefix: str = "") -> str:
    return "".join(f"{prefix}{x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())


def _obj_text(V: np.ndarray, F: np.ndarray) -> str:
    """Wavefront OBJ, coordinates written exactly (shortest round-trip repr), 1-based faces."""
    faces = "".join(f"f {a} {b} {c}\n" for a, b, c in (F + 1).tolist())
    return "# written by facecorr\n" + _xyz_lines(V, "v ") + faces


def _off_text(V: np.ndarray, F: np.ndarray) -> str:
    """OFF, coordinates written exactly (shortest round-trip repr)."""
    faces = "".join(f"3 {a} {b} {c}\n" for a, b, c in F.tolist())
    return f"OFF\n{len(V)} {len(F)} 0\n" + _xyz_lines(V) + faces


def save_mesh(path, mesh_or_VF, units: str | None = None) -> None:
    """Write a mesh: PLY (binary, float64), OBJ, OFF and WRL (text, exact round-trip digits) by our
    writers; STL and GLB (float32 by format) through trimesh.

    Parameters
    ----------
    path : str or Path, the format is taken from the extension.
    mesh_or_VF : Mesh, or a pair (V (N, 3) mm, F (M, 3) int).
    units : "mm", "cm", "m" or None
        Units to write in. None: the mesh's own source units (``mesh.units``; mm for a (V, F) pair),
        so a loaded scan goes back in its own units.

    Raises
    ------
    MeshFileError for an unknown format or an unwritable path; MeshError for an invalid mesh;
    UnitsError for unknown units. Nothing is written on error.
    """
    path = Path(path)
    fmt = _format_of(path)
    if isinstance(mesh_or_VF, Mesh):
        mesh = mesh_or_VF
    else:
        try:
            V, F = mesh_or_VF
        except (TypeError, ValueError):
            raise MeshError("save_mesh needs a Mesh or a (vertices, faces) pair") from None
        mesh = Mesh(V, F)
    factor = _unit_factor(units if units is not None else mesh.units)
    V = mesh.vertices / factor
    F = mesh.faces
    if fmt == "wrl":
        data = write_wrl_text(V, F).encode("ascii")
    elif fmt == "ply":
        data = _ply_bytes(V, F)
    elif fmt == "obj":
        data = _obj_text(V, F).encode("ascii")
    elif fmt == "off":
        data = _off_text(V, F).encode("ascii")
    else:
        import trimesh

        tm = trimesh.Trimesh(vertices=V, faces=F, process=False, validate=False)
        try:
            data = tm.export(file_type=fmt)
        except Exception as e:  # noqa: BLE001
            raise MeshFileError(f"{path}: cannot export {fmt.upper()} ({_one_line(e)})") from None
        if isinstance(data, str):
            data = data.encode("utf-8")
    _atomic_write(path, data)


# ----------------------------------------------------------------------------- VRML 2.0

_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|#[^\n]*|[{}\[\]]|[^\s{}\[\],"#]+|,')
_SCALAR_WORDS = {"TRUE", "FALSE", "NULL"}
_NONFINITE = {"nan", "inf", "infinity"}  # not VRML, but printf writes them; reported as NaN/inf
# A bracketed list without nodes, strings or comments (the big point / coordIndex arrays).
_RAW_BLOCK = re.compile(r"\[([^\[\]{}\"#]*)\]")


class _Node:
    __slots__ = ("type", "fields")

    def __init__(self, type_: str):
        self.type = type_
        self.fields: dict = {}


class _WrlParser:
    """Generic VRML97 node parser (no schema): node = [DEF n] Type { (field value)* } | USE n.

    A field value is a node, a bracketed list of nodes or scalars, or a run of scalar tokens
    (numbers, strings, TRUE/FALSE/NULL). PROTO/EXTERNPROTO definitions and ROUTEs are skipped.
    """

    def __init__(self, text: str, name: str):
        self.text = text
        self.name = name
        toks, pos = [], []
        self.raw: list[tuple[int, int]] = []  # (start, end) of long plain bracketed number lists

        def tokenize(a: int, b: int) -> None:
            for m in _TOKEN.finditer(text, a, b):
                t = m.group()
                if t[0] == "#" or t == ",":
                    continue
                toks.append(t)
                pos.append(m.start())

        done = 0
        for m in _RAW_BLOCK.finditer(text):
            a, b = m.span(1)
            line_start = text.rfind("\n", 0, m.start()) + 1
            if b - a < 1000 or "#" in text[line_start:m.start()]:
                continue  # short, or possibly inside a comment: the token path handles it
            tokenize(done, m.start())
            toks += ["[", f"\x00{len(self.raw)}", "]"]
            pos += [m.start(), a, b]
            self.raw.append((a, b))
            done = m.end()
        tokenize(done, len(text))
        self.toks, self.pos, self.i = toks, pos, 0
        self.defs: dict[str, _Node] = {}

    def error(self, msg: str, at: int | None = None) -> MeshFileError:
        k = self.i if at is None else at
        if k < len(self.pos):
            line = self.text.count("\n", 0, self.pos[k]) + 1
            return MeshFileError(f"{self.name}: broken VRML at line {line}: {msg}")
        return MeshFileError(f"{self.name}: broken VRML: {msg} (unexpected end of file)")

    def peek(self, k: int = 0) -> str | None:
        j = self.i + k
        return self.toks[j] if j < len(self.toks) else None

    def next(self) -> str:
        if self.i >= len(self.toks):
            raise self.error("file ends too early")
        t = self.toks[self.i]
        self.i += 1
        return t

    def expect(self, t: str) -> None:
        got = self.next()
        if got != t:
            raise self.error(f"expected {t!r}, found {got!r}", self.i - 1)

    @staticmethod
    def is_scalar(t: str | None) -> bool:
        return t is not None and (t[0] in '"+-.0123456789' or t in _SCALAR_WORDS
                                  or t.lower() in _NONFINITE)

    def starts_node(self) -> bool:
        t = self.peek()
        if t in ("DEF", "USE"):
            return True
        return t is not None and not self.is_scalar(t) and t not in "{}[]" and self.peek(1) == "{"

    def skip_block(self) -> None:
        """Skip a balanced {...} or [...] starting at the current token."""
        depth = 0
        while True:
            t = self.next()
            if t in "{[":
                depth += 1
            elif t in "}]":
                depth -= 1
                if depth == 0:
                    return

    def parse_file(self) -> list:
        nodes = []
        while self.peek() is not None:
            t = self.peek()
            if t == "ROUTE":
                self.i += 4  # ROUTE a.b TO c.d
            elif t in ("PROTO", "EXTERNPROTO"):
                self.i += 2
                while self.peek() is not None and self.peek() in "[{":
                    self.skip_block()
                    if t == "EXTERNPROTO" and self.peek() is not None and self.peek()[0] == '"':
                        self.i += 1
            elif self.starts_node():
                nodes.append(self.parse_node())
            else:
                raise self.error(f"unexpected {t!r} at the top level")
        return nodes

    def parse_node(self) -> _Node | None:
        t = self.next()
        if t == "USE":
            name = self.next()
            if name not in self.defs:
                raise self.error(f"USE of undefined name {name!r}", self.i - 1)
            return self.defs[name]
        def_name = None
        if t == "DEF":
            def_name = self.next()
            t = self.next()
        node = _Node(t)
        if def_name is not None:
            self.defs[def_name] = node
        self.expect("{")
        while True:
            f = self.peek()
            if f is None:
                raise self.error("missing '}'")
            if f == "}":
                self.i += 1
                return node
            if f in ("ROUTE",):
                self.i += 4
                continue
            self.i += 1
            if f in "{[]" or self.is_scalar(f):
                raise self.error(f"expected a field name in {node.type}, found {f!r}", self.i - 1)
            node.fields[f] = self.parse_value(f)

    def parse_value(self, field: str):
        t = self.peek()
        if t == "[":
            self.i += 1
            raw = self.peek()
            if raw is not None and raw[0] == "\x00":
                self.i += 2  # the block and its "]"
                a, b = self.raw[int(raw[1:])]
                return _RawList(self.text, a, b, self)
            if self.starts_node() or self.peek() == "]":
                items = []
                while self.peek() != "]":
                    if self.peek() is None:
                        raise self.error(f"missing ']' after {field}")
                    if not self.starts_node():
                        raise self.error(f"expected a node in {field}, found {self.peek()!r}")
                    items.append(self.parse_node())
                self.i += 1
                return items
            start = self.i
            while True:
                t = self.peek()
                if t is None:
                    raise self.error(f"missing ']' after {field}")
                if t == "]":
                    break
                if not self.is_scalar(t):
                    raise self.error(f"unexpected {t!r} in {field}")
                self.i += 1
            vals = self.toks[start:self.i]
            self.i += 1
            return _ScalarList(vals, start, self)
        if self.starts_node():
            return self.parse_node()
        start = self.i
        while self.is_scalar(self.peek()):
            self.i += 1
        if self.i == start:
            raise self.error(f"missing value for {field}")
        return _ScalarList(self.toks[start:self.i], start, self)


class _RawList:
    """A long bracketed list of plain numbers, kept as text and converted in one go."""

    __slots__ = ("text", "a", "b", "parser")

    def __init__(self, text, a, b, parser):
        self.text, self.a, self.b, self.parser = text, a, b, parser

    @property
    def toks(self) -> list[str]:
        return self.text[self.a:self.b].replace(",", " ").split()

    def _convert(self, dtype, field: str, what: str) -> np.ndarray:
        toks = self.toks
        try:
            return np.array(toks, dtype=dtype)
        except (ValueError, OverflowError):
            check = _is_float if dtype is np.float64 else _is_int
            bad = next(t for t in toks if not check(t))
            at = self.text.find(bad, self.a, self.b)
            line = self.text.count("\n", 0, at) + 1
            raise MeshFileError(f"{self.parser.name}: broken VRML at line {line}: {bad!r} is not "
                                f"{what} in {field}") from None

    def floats(self, field: str) -> np.ndarray:
        return self._convert(np.float64, field, "a number")

    def ints(self, field: str) -> np.ndarray:
        return self._convert(np.int64, field, "an integer")


class _ScalarList:
    """Raw scalar tokens of a field, converted on demand."""

    __slots__ = ("toks", "start", "parser")

    def __init__(self, toks, start, parser):
        self.toks, self.start, self.parser = toks, start, parser

    def floats(self, field: str) -> np.ndarray:
        try:
            return np.array(self.toks, dtype=np.float64)
        except ValueError:
            bad = next(k for k, t in enumerate(self.toks) if not _is_float(t))
            raise self.parser.error(f"{self.toks[bad]!r} is not a number in {field}",
                                    self.start + bad) from None

    def ints(self, field: str) -> np.ndarray:
        try:
            return np.array(self.toks, dtype=np.int64)
        except (ValueError, OverflowError):
            bad = next(k for k, t in enumerate(self.toks) if not _is_int(t))
            raise self.parser.error(f"{self.toks[bad]!r} is not an integer in {field}",
                                    self.start + bad) from None


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


def _is_int(t: str) -> bool:
    try:
        int(t)
        return True
    except ValueError:
        return False


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    """VRML's rotation field (x, y, z, angle in radians) as a (3, 3) matrix."""
    return transforms.axis_angle(axis_angle[:3], axis_angle[3])


def _transform_matrix(node: _Node, p: _WrlParser) -> np.ndarray:
    """4x4 of a VRML Transform: T C R SR S -SR -C."""

    def vec(field, default):
        v = node.fields.get(field)
        if v is None:
            return np.array(default, float)
        a = v.floats(field) if isinstance(v, _ScalarList) else None
        if a is None or len(a) != len(default):
            raise p.error(f"Transform.{field} needs {len(default)} numbers")
        return a

    def h(m3=None, t=None):
        m = np.eye(4)
        if m3 is not None:
            m[:3, :3] = m3
        if t is not None:
            m[:3, 3] = t
        return m

    T = h(t=vec("translation", [0, 0, 0]))
    C = h(t=vec("center", [0, 0, 0]))
    R = h(_rotation(vec("rotation", [0, 0, 1, 0])))
    SR = h(_rotation(vec("scaleOrientation", [0, 0, 1, 0])))
    S = h(np.diag(vec("scale", [1, 1, 1])))
    return T @ C @ R @ SR @ S @ np.linalg.inv(SR) @ np.linalg.inv(C)


def _collect_face_sets(nodes, p: _WrlParser, M: np.ndarray, out: list, depth: int = 0) -> None:
    if depth > 100:
        raise p.error("nodes nested more than 100 deep (a USE cycle?)")
    for node in nodes:
        if not isinstance(node, _Node):
            continue
        if node.type == "IndexedFaceSet":
            out.append((node, M))
            continue
        here = M @ _transform_matrix(node, p) if node.type == "Transform" else M
        if node.type == "Shape":
            g = node.fields.get("geometry")
            if isinstance(g, _Node):
                _collect_face_sets([g], p, here, out, depth + 1)
        for key in ("children", "level"):  # Group/Transform/Anchor/Collision/Billboard, LOD
            kids = node.fields.get(key)
            if isinstance(kids, _Node):
                kids = [kids]
            if isinstance(kids, list):
                _collect_face_sets(kids, p, here, out, depth + 1)
                if key == "level":
                    break


def read_wrl(path) -> tuple[np.ndarray, np.ndarray]:
    """Raw (V, F) of a VRML 2.0 file: all IndexedFaceSets merged, polygons fan-triangulated.

    Polygons with fewer than 3 vertices are dropped (they count in ``n_degenerate_faces_dropped``
    of :func:`load_mesh` because they are kept as degenerate triangles here). Indices are not
    range-checked here (:func:`load_mesh` does). Raises MeshFileError for broken syntax or
    another VRML version.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    text = raw.decode("utf-8", errors="replace")
    head = text.lstrip("\ufeff")[:64]
    if not head.startswith("#VRML"):
        raise MeshFileError(f"{path}: not a VRML file (no '#VRML V2.0' header)")
    if not head.startswith("#VRML V2.0"):
        raise MeshFileError(f"{path}: only VRML 2.0 is supported, found {head.splitlines()[0]!r}")
    p = _WrlParser(text, str(path))
    nodes = p.parse_file()
    sets: list = []
    _collect_face_sets(nodes, p, np.eye(4), sets)
    Vs, Fs, off = [], [], 0
    for node, M in sets:
        coord = node.fields.get("coord")
        if not isinstance(coord, _Node):
            continue
        pts = coord.fields.get("point")
        pts = pts.floats("point") if isinstance(pts, (_ScalarList, _RawList)) else np.zeros(0)
        if len(pts) % 3:
            raise MeshFileError(f"{path}: Coordinate.point has {len(pts)} numbers, not a multiple of 3")
        V = pts.reshape(-1, 3)
        if not np.allclose(M, np.eye(4)):
            V = V @ M[:3, :3].T + M[:3, 3]
        ci = node.fields.get("coordIndex")
        idx = ci.ints("coordIndex") if isinstance(ci, (_ScalarList, _RawList)) else np.zeros(0, np.int64)
        F = _fan_triangulate(idx)
        ccw = node.fields.get("ccw")
        if isinstance(ccw, _ScalarList) and ccw.toks == ["FALSE"]:
            F = F[:, ::-1]
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
    if not Vs:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(Vs), np.concatenate(Fs)


def _fan_triangulate(idx: np.ndarray) -> np.ndarray:
    """coordIndex with -1 separators -> (T, 3) triangles (fans); short polygons -> degenerate."""
    idx = np.asarray(idx, np.int64)
    if len(idx) == 0:
        return np.zeros((0, 3), np.int64)
    if idx[-1] != -1:
        idx = np.append(idx, -1)
    ends = np.flatnonzero(idx == -1)
    starts = np.concatenate([[0], ends[:-1] + 1])
    lengths = ends - starts
    # Fast path: all triangles.
    if np.all(lengths == 3):
        return idx[np.stack([starts, starts + 1, starts + 2], axis=1)]
    tris = []
    for s, n in zip(starts, lengths):
        if n == 0:
            continue
        if n < 3:  # keep as a degenerate triangle so that it is counted and dropped
            poly = idx[s:s + n]
            tris.append([poly[0], poly[-1], poly[-1]])
            continue
        for k in range(1, n - 1):
            tris.append([idx[s], idx[s + k], idx[s + k + 1]])
    return np.array(tris, np.int64).reshape(-1, 3)


def write_wrl_text(V: np.ndarray, F: np.ndarray) -> str:
    """VRML 2.0 text of one Shape with an IndexedFaceSet (coordinates written exactly, %.17g)."""
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    pts = ",\n".join(f"{x:.17g} {y:.17g} {z:.17g}" for x, y, z in V.tolist())
    idx = ",\n".join(f"{a}, {b}, {c}, -1" for a, b, c in F.tolist())
    return ("#VRML V2.0 utf8\n# written by facecorr\n"
            "Shape {\n geometry IndexedFaceSet {\n  coord Coordinate {\n   point [\n"
            f"{pts}\n   ]\n  }}\n  coordIndex [\n{idx}\n  ]\n }}\n}}\n")


def write_wrl(path, V: np.ndarray, F: np.ndarray) -> None:
    """Write (V, F) as VRML 2.0 (coordinates as given, no unit conversion)."""
    _atomic_write(Path(path), write_wrl_text(V, F).encode("ascii"))


# ----------------------------------------------------------------------------- BU-3DFE .bnd


def load_bnd(path, to_mm: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Read a BU-3DFE landmark file: one ``index x y z`` per line.

    Parameters
    ----------
    path : str or Path.
    to_mm : factor applied to the coordinates (the scan's ``mesh.to_mm`` to get millimetres).

    Returns
    -------
    ids : (L,) int64, the vertex index given on each line.
    points : (L, 3) float64, the coordinates (times ``to_mm``).

    Blank lines and ``#`` comments are skipped; anything else that is not four numbers (an
    integer index and three finite coordinates) raises MeshFileError naming the line.
    """
    path = Path(path)
    _check_readable_text(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    ids, pts = [], []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 4:
            raise MeshFileError(f"{path}: line {n}: expected 'index x y z', found {len(parts)} fields")
        try:
            idx = float(parts[0])
            xyz = [float(x) for x in parts[1:]]
        except ValueError:
            raise MeshFileError(f"{path}: line {n}: not numbers: {s[:60]!r}") from None
        if not idx.is_integer() or idx < 0:
            raise MeshFileError(f"{path}: line {n}: index {parts[0]!r} is not a non-negative integer")
        if not all(math.isfinite(x) for x in xyz):
            raise MeshFileError(f"{path}: line {n}: NaN or infinite coordinate")
        ids.append(int(idx))
        pts.append(xyz)
    if not ids:
        raise MeshFileError(f"{path}: no landmarks in the file")
    return np.array(ids, np.int64), np.array(pts, np.float64) * float(to_mm)


def _check_readable_text(path: Path) -> None:
    if not path.exists():
        raise MeshFileError(f"{path}: no such file")
    if path.is_dir():
        raise MeshFileError(f"{path}: is a directory")
