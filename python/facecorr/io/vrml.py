"""VRML 2.0 (``.wrl``/``.vrml``, e.g. BU-3DFE) meshes: the parser :func:`read_wrl` (the writer is
in :mod:`facecorr.io.write`).

Every ``IndexedFaceSet`` reached through ``children`` / ``level`` / ``Shape.geometry`` is read
(``coord Coordinate { point [...] }`` or ``USE``, ``coordIndex [... -1 ...]`` polygons,
fan-triangulated; ``ccw FALSE`` flips them); several shapes are merged; ``Transform`` nodes are
applied; normal nodes, PROTOs and ROUTEs are ignored. A gzip-compressed file
(allowed by the VRML spec) is decompressed. Long plain number lists
(> 1000 characters) are converted in one numpy call. Coordinates are returned as in the file (no
unit conversion; :func:`facecorr.io.load_mesh` does that). Syntax errors are one-line
:class:`~facecorr.errors.MeshFileError` naming the line.

Colour (:func:`read_wrl_with_appearance`): per-vertex ``color Color { color [...] }``
(``colorPerVertex TRUE``, the default; with ``colorIndex`` or indexed like the points), or a
texture: ``texCoord TextureCoordinate { point [...] }`` (with ``texCoordIndex`` or indexed like
``coordIndex``) and the Shape's ``appearance Appearance { texture ImageTexture { url "..." } }``
(the first url that names a readable image, relative to the file's folder), as BU-3DFE writes
it. Several shapes: kept when all have vertex colours, or all share one texture image; per-face
colours, ``PixelTexture`` and anything unusable give no colour and a note (the file still loads).
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numpy as np

from ..errors import MeshFileError
from ..geometry import transforms
from .appearance import Appearance, read_image

__all__ = ["read_wrl", "read_wrl_with_appearance"]

_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|#[^\n]*|[{}\[\]]|[^\s{}\[\],"#]+|,')
_MAX_DEPTH = 100  # node nesting (real files: < 10)
_MAX_VISITS = 100_000  # node instances after DEF/USE expansion
_MAX_FACE_SETS = 10_000  # IndexedFaceSet instances after DEF/USE expansion
_MAX_VERTICES = 100_000_000  # vertices of all instances (a face scan: ~1e5)
#: decompressed size of a gzip-compressed .wrl (20M vertices of text ≈ 2 GB; a "zip bomb" is more)
MAX_GUNZIPPED_BYTES = 4 * 1024**3
_SCALAR_WORDS = {"TRUE", "FALSE", "NULL"}
_NONFINITE = {"nan", "inf", "infinity"}  # not VRML, but printf writes them; reported as NaN/inf
# A bracketed list without nodes, strings or comments (the big point / coordIndex arrays).
_RAW_BLOCK = re.compile(r"\[([^\[\]{}\"#]*)\]")


class _Node:
    """A parsed VRML node: its type name and ``fields`` (name -> node, list or scalar list)."""

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
        self.depth = 0  # nesting of parse_node (bounded: Python recursion)

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
        if self.depth >= _MAX_DEPTH:
            raise self.error(f"nodes nested more than {_MAX_DEPTH} deep")
        self.depth += 1
        try:
            return self._parse_node()
        finally:
            self.depth -= 1

    def _parse_node(self) -> _Node | None:
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
            k, why = _bad_token(toks, dtype, what)
            at = self.text.find(toks[k], self.a, self.b)
            line = self.text.count("\n", 0, at) + 1
            raise MeshFileError(f"{self.parser.name}: broken VRML at line {line}: {toks[k][:40]!r} "
                                f"{why} in {field}") from None

    def floats(self, field: str) -> np.ndarray:
        return self._convert(np.float64, field, "a number")

    def ints(self, field: str) -> np.ndarray:
        return self._convert(np.int64, field, "an integer")


class _ScalarList:
    """Raw scalar tokens of a field, converted on demand."""

    __slots__ = ("toks", "start", "parser")

    def __init__(self, toks, start, parser):
        self.toks, self.start, self.parser = toks, start, parser

    def _convert(self, dtype, field: str, what: str) -> np.ndarray:
        try:
            return np.array(self.toks, dtype=dtype)
        except (ValueError, OverflowError):
            k, why = _bad_token(self.toks, dtype, what)
            raise self.parser.error(f"{self.toks[k][:40]!r} {why} in {field}", self.start + k) from None

    def floats(self, field: str) -> np.ndarray:
        return self._convert(np.float64, field, "a number")

    def ints(self, field: str) -> np.ndarray:
        return self._convert(np.int64, field, "an integer")


def _bad_token(toks: list, dtype, what: str) -> tuple[int, str]:
    """(position, reason) of the first token of ``toks`` that numpy cannot convert to ``dtype``."""
    for k, t in enumerate(toks):
        if dtype is np.float64:
            if not _is_float(t):
                return k, f"is not {what}"
        elif not _is_int(t):
            return k, f"is not {what}"
        elif not -2**63 <= int(t) < 2**63:
            return k, "is out of range"
    return 0, f"cannot be converted to {what}"  # not reached: numpy converts like float()/int()


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
        if not np.isfinite(a).all():
            raise p.error(f"Transform.{field} has NaN or infinite numbers", v.start)
        return a

    def h(m3=None, t=None):
        m = np.eye(4)
        if m3 is not None:
            m[:3, :3] = m3
        if t is not None:
            m[:3, 3] = t
        return m

    with np.errstate(all="ignore"):  # huge values overflow to inf, reported by load_mesh
        return _trs(vec, h)


def _trs(vec, h) -> np.ndarray:
    T = h(t=vec("translation", [0, 0, 0]))
    C = h(t=vec("center", [0, 0, 0]))
    R = h(_rotation(vec("rotation", [0, 0, 1, 0])))
    SR = h(_rotation(vec("scaleOrientation", [0, 0, 1, 0])))
    S = h(np.diag(vec("scale", [1, 1, 1])))
    return T @ C @ R @ SR @ S @ np.linalg.inv(SR) @ np.linalg.inv(C)


def _collect_face_sets(nodes, p: _WrlParser, M: np.ndarray, out: list, depth: int = 0,
                       visits: list | None = None, shape: _Node | None = None) -> None:
    """Append (IndexedFaceSet node, 4x4 world matrix M, its Shape node or None) of every face set
    under ``nodes`` to ``out``.

    At most ``_MAX_VISITS`` node instances and ``_MAX_FACE_SETS`` face sets (USE of USE of ... can
    expand exponentially: a 40-line file would take forever)."""
    if visits is None:
        visits = [0]
    if depth > 100:
        raise p.error("nodes nested more than 100 deep (a USE cycle?)")
    for node in nodes:
        if not isinstance(node, _Node):
            continue
        visits[0] += 1
        if visits[0] > _MAX_VISITS or len(out) > _MAX_FACE_SETS:
            raise MeshFileError(f"{p.name}: more than {_MAX_VISITS} nodes or {_MAX_FACE_SETS} "
                                f"IndexedFaceSets once DEF/USE are expanded (USE of USE ...?)")
        if node.type == "IndexedFaceSet":
            out.append((node, M, shape))
            continue
        with np.errstate(all="ignore"):
            here = M @ _transform_matrix(node, p) if node.type == "Transform" else M
        if node.type == "Shape":
            g = node.fields.get("geometry")
            if isinstance(g, _Node):
                _collect_face_sets([g], p, here, out, depth + 1, visits, node)
        for key in ("children", "level"):  # Group/Transform/Anchor/Collision/Billboard, LOD
            kids = node.fields.get(key)
            if isinstance(kids, _Node):
                kids = [kids]
            if isinstance(kids, list):
                _collect_face_sets(kids, p, here, out, depth + 1, visits)
                if key == "level":
                    break


def _gunzip(raw: bytes, path: Path, limit: int | None = None) -> bytes:
    """Decompress a gzip member (or several), refusing output beyond ``limit`` bytes.

    Streams in 64 MiB pieces so a small file that inflates to terabytes (a "zip bomb") is stopped
    at the limit instead of exhausting memory.
    """
    limit = MAX_GUNZIPPED_BYTES if limit is None else limit
    out, total, data = [], 0, raw
    try:
        while data:
            d = zlib.decompressobj(16 + zlib.MAX_WBITS)
            while True:
                piece = d.decompress(data, 64 * 1024**2)
                total += len(piece)
                if total > limit:
                    raise MeshFileError(f"{path}: gzip-compressed VRML inflates to more than "
                                        f"{limit / 1024**3:.3g} GiB; not a face scan (or a zip bomb)")
                out.append(piece)
                data = d.unconsumed_tail
                if d.eof or not (data or piece):  # done, or input spent and nothing buffered
                    break
            if not d.eof:
                raise MeshFileError(f"{path}: broken gzip-compressed VRML file (truncated)")
            data = d.unused_data.lstrip(b"\x00")  # concatenated members; padding NULs end it
    except zlib.error as e:
        raise MeshFileError(f"{path}: broken gzip-compressed VRML file ({e})") from None
    return b"".join(out)


def read_wrl(path) -> tuple[np.ndarray, np.ndarray]:
    """Raw (V, F) of a VRML 2.0 file: all IndexedFaceSets merged, polygons fan-triangulated.

    Polygons with fewer than 3 vertices are dropped (they count in ``n_degenerate_faces_dropped``
    of :func:`load_mesh` because they are kept as degenerate triangles here). Indices are not
    range-checked here (:func:`load_mesh` does). Raises MeshFileError for broken syntax or
    another VRML version.
    """
    V, F, _ = read_wrl_with_appearance(path)
    return V, F


def read_wrl_with_appearance(path) -> tuple[np.ndarray, np.ndarray, Appearance]:
    """Raw (V, F, appearance) of a VRML 2.0 file: :func:`read_wrl` and the file's colour
    (module docstring), indexed like V and F."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    if raw[:2] == b"\x1f\x8b":  # VRML allows gzip-compressed .wrl files
        raw = _gunzip(raw, path)
    if b"\x00" in raw:
        raise MeshFileError(f"{path}: binary data (NUL bytes) in a VRML file: not a VRML file, or a broken one")
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
    Vs, Fs, looks, off = [], [], [], 0
    for node, M, shape in sets:
        coord = node.fields.get("coord")
        if not isinstance(coord, _Node):
            continue
        pts = coord.fields.get("point")
        pts = pts.floats("point") if isinstance(pts, (_ScalarList, _RawList)) else np.zeros(0)
        if len(pts) % 3:
            raise MeshFileError(f"{path}: Coordinate.point has {len(pts)} numbers, not a multiple of 3")
        V = pts.reshape(-1, 3)
        if not np.allclose(M, np.eye(4)):
            with np.errstate(all="ignore"):  # overflow -> inf, reported by load_mesh
                V = V @ M[:3, :3].T + M[:3, 3]
        ci = node.fields.get("coordIndex")
        idx = ci.ints("coordIndex") if isinstance(ci, (_ScalarList, _RawList)) else np.zeros(0, np.int64)
        corners = _fan_corners(idx)
        F = idx[corners] if len(corners) else np.zeros((0, 3), np.int64)
        ccw = node.fields.get("ccw")
        flip = isinstance(ccw, _ScalarList) and ccw.toks == ["FALSE"]
        if flip:
            F = F[:, ::-1]
        looks.append(_face_set_look(node, shape, idx, corners[:, ::-1] if flip else corners, len(V), path))
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
        if off > _MAX_VERTICES:
            raise MeshFileError(f"{path}: more than {_MAX_VERTICES} vertices once DEF/USE are expanded")
    if not Vs:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), Appearance()
    return np.concatenate(Vs), np.concatenate(Fs), _merge_looks(looks, path)


def _fan_corners(idx: np.ndarray) -> np.ndarray:
    """coordIndex with -1 separators -> (T, 3) positions in ``idx`` of each triangle's corners
    (fans; a polygon with < 3 vertices -> a degenerate triangle, counted and dropped later)."""
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
        return np.stack([starts, starts + 1, starts + 2], axis=1)
    tris = []
    for s, n in zip(starts.tolist(), lengths.tolist()):
        if n == 0:
            continue
        if n < 3:  # keep as a degenerate triangle so that it is counted and dropped
            tris.append([s, s + n - 1, s + n - 1])
            continue
        for k in range(1, n - 1):
            tris.append([s, s + k, s + k + 1])
    return np.array(tris, np.int64).reshape(-1, 3)


def _numbers(node, field: str, kind: str = "floats"):
    """A node's number list field as an array, None if absent (or not a number list)."""
    v = node.fields.get(field) if isinstance(node, _Node) else None
    if not isinstance(v, (_ScalarList, _RawList)):
        return None
    return v.floats(field) if kind == "floats" else v.ints(field)


def _corner_index(node, field: str, idx: np.ndarray, corners: np.ndarray, n_items: int):
    """(T, 3) item ids of the triangle corners, from the index field ``field`` (laid out like
    coordIndex) or, when absent or empty, from coordIndex itself; None if out of range."""
    own = _numbers(node, field, "ints")
    ids = own if own is not None and len(own) else idx
    if len(corners) and corners.max() >= len(ids):
        return None
    out = ids[corners] if len(corners) else np.zeros((0, 3), np.int64)
    if len(out) and (out.min() < 0 or out.max() >= n_items):
        return None
    return out


def _face_set_look(node, shape, idx, corners, n_points: int, path: Path) -> dict:
    """One IndexedFaceSet's colour: {"colors": (n_points, 3) | None, "uv": (T, 3, 2) | None,
    "image": path | None, "note": str | None}."""
    look = {"colors": None, "uv": None, "image": None, "note": None}
    vids = idx[corners] if len(corners) else np.zeros((0, 3), np.int64)
    if vids.size and (vids.min() < 0 or vids.max() >= n_points):
        return look  # load_mesh reports the out-of-range face
    color = node.fields.get("color")
    if isinstance(color, _Node):
        c = _numbers(color, "color")
        per_vertex = node.fields.get("colorPerVertex")
        if isinstance(per_vertex, _ScalarList) and per_vertex.toks == ["FALSE"]:
            look["note"] = "per-face colours (colorPerVertex FALSE) are not supported"
        elif c is None or len(c) % 3:
            look["note"] = "broken Color node"
        else:
            c = c.reshape(-1, 3)
            ids = _corner_index(node, "colorIndex", idx, corners, len(c))
            if ids is None:
                look["note"] = "colour indices out of range"
            else:
                # a vertex takes the colour of its corners (one per vertex in practice); vertices
                # in no triangle are never sampled and get mid-grey
                vc = np.full((n_points, 3), 0.5)
                vc[vids.ravel()] = c[ids.ravel()]
                look["colors"] = vc
    tex = node.fields.get("texCoord")
    if isinstance(tex, _Node):
        pts = _numbers(tex, "point")
        app = shape.fields.get("appearance") if isinstance(shape, _Node) else None
        img = app.fields.get("texture") if isinstance(app, _Node) else None
        if pts is None or len(pts) % 2:
            look["note"] = "broken TextureCoordinate node"
        elif not isinstance(img, _Node) or img.type != "ImageTexture":
            look["note"] = "texture coordinates without an ImageTexture"
        else:
            uv = pts.reshape(-1, 2)
            ids = _corner_index(node, "texCoordIndex", idx, corners, len(uv))
            urls = img.fields.get("url")
            names = [t.strip('"') for t in urls.toks] if isinstance(urls, _ScalarList) else []
            found = [path.parent / n for n in names if n and (path.parent / n).is_file()]
            if ids is None:
                look["note"] = "texture coordinate indices out of range"
            elif not found:
                look["note"] = f"texture image {names[0] if names else '(no url)'!r} not found beside the scan"
            else:
                look["uv"], look["image"] = uv[ids], found[0]
    return look


def _merge_looks(looks: list, path: Path) -> Appearance:
    """The file's colour from its face sets' (see the module docstring)."""
    app = Appearance()
    for lk in looks:
        if lk["note"]:
            app.add_note(lk["note"])
    if all(lk["colors"] is not None for lk in looks):
        app.vertex_colors = np.concatenate([lk["colors"] for lk in looks])
    elif any(lk["colors"] is not None for lk in looks):
        app.add_note("colours on some shapes only: not used")
    images = {lk["image"] for lk in looks}
    if len(images) == 1 and None not in images:
        try:
            app.texture = read_image(images.pop())
            app.corner_uv = np.concatenate([lk["uv"] for lk in looks])
        except ValueError as e:
            app.add_note(f"{e}: texture not used")
    elif any(lk["image"] is not None for lk in looks):
        app.add_note("several texture images, or texture on some shapes only: texture not used")
    return app
