"""Wavefront OBJ: the reader behind :func:`facecorr.io.load_mesh`, with the file's colour.

:func:`read_obj` reads ``v`` lines (x y z, optionally followed by r g b: the common per-vertex
colour extension), ``vt`` texture coordinates, ``f`` lines (``i``, ``i/t``, ``i//n``, ``i/t/n``;
negative = relative to the elements defined so far, per the spec; polygons fan-triangulated,
faces with < 3 vertices kept as degenerate triangles for :func:`facecorr.io.load._clean` to count
and drop), ``usemtl`` / ``mtllib`` (the material files' ``map_Kd`` texture image). File order is
kept; CRLF, a UTF-8 BOM, line continuations and non-UTF-8 bytes in comments are handled. Broken
numbers -> MeshFileError naming the line; index 0 or a relative index before the first vertex ->
MeshError. The common plain files (``v x y z [r g b]``, ``vt u v``, triangles ``i`` / ``i/t`` /
``i/t/n`` with positive indices) are read in a few numpy calls (:func:`_obj_fast`).

Colour (returned as an :class:`~facecorr.io.appearance.Appearance`):

* per-vertex colours when every ``v`` line has 6 or 7 numbers; values above 1 mean the file uses
  0-255 (some exporters write that), so all are divided by 255 then;
* a texture when every triangle corner has a texture index, and the materials the triangles use
  (all materials of the ``mtllib`` files if no ``usemtl`` is given) name one and the same
  ``map_Kd`` image, which Pillow reads. Anything else: no texture, and ``note`` says why.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshFileError
from .appearance import Appearance, read_image, read_mtl

__all__ = ["read_obj", "read_text"]

# Largest vertex index accepted before the range check (keeps int64 arithmetic exact).
MAX_INDEX = 2**53


def read_text(path: Path, fmt: str) -> str:
    """Text of an OBJ/OFF file: UTF-8 with undecodable bytes replaced (they can only matter in
    comments and names, which are ignored), a leading BOM dropped; binary data -> MeshFileError."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read: {e.strerror or e}") from None
    if b"\x00" in raw:
        an = "an" if fmt.upper()[0] in "AEFHILMNORSX" else "a"
        raise MeshFileError(f"{path}: binary data (NUL bytes) in a text {fmt.upper()} file: not "
                            f"{an} {fmt.upper()} file, or a broken one")
    text = raw.decode("utf-8", errors="replace")
    return text[1:] if text.startswith("\ufeff") else text


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, Appearance]:
    """Raw (V (N, 3), F (M, 3), appearance) of a Wavefront OBJ (see the module docstring)."""
    text = read_text(path, "obj")
    if "\\" in text:  # line continuation: a backslash at the end of a line
        text = re.sub(r"\\[ \t]*(?:\r\n|\r|\n)", " ", text)
    lines = text.splitlines()
    parsed = _obj_fast(lines, "usemtl" in text or "mtllib" in text)
    if parsed is None:
        parsed = _obj_general(path, lines)
    return parsed["V"], parsed["F"], _appearance(path, parsed)


def _obj_general(path: Path, lines: list) -> dict:
    """The line-by-line reader (any valid OBJ; errors name the line)."""
    verts: list = []
    cols: list = []
    vts: list = []
    tris: list = []
    tex: list = []
    mat: list = []
    materials: list = []
    mtllibs: list = []
    vt_bad = False
    current = -1
    nv = 0
    for n, line in enumerate(lines, 1):
        s = line.lstrip()
        if not s or s[0] not in "vfum":
            continue
        parts = s.split("#", 1)[0].split() if "#" in s else s.split()
        if not parts:
            continue
        key = parts[0]
        if key == "v":
            if len(parts) < 4:
                raise MeshFileError(f"{path}: broken OBJ at line {n}: a vertex needs x y z, "
                                    f"found {len(parts) - 1} numbers")
            try:
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            except ValueError:
                raise MeshFileError(f"{path}: broken OBJ at line {n}: not numbers: "
                                    f"{' '.join(parts[1:4])[:60]!r}") from None
            try:
                cols.append((float(parts[4]), float(parts[5]), float(parts[6])) if len(parts) in (7, 8) else None)
            except ValueError:
                cols.append(None)
            nv += 1
        elif key == "vt":
            try:
                vts.append((float(parts[1]), float(parts[2]) if len(parts) > 2 else 0.0))
            except (ValueError, IndexError):
                vts.append((np.nan, np.nan))
                vt_bad = True
        elif key == "usemtl":
            name = " ".join(parts[1:])
            if name not in materials:
                materials.append(name)
            current = materials.index(name)
        elif key == "mtllib":
            mtllibs.extend(parts[1:])
        elif key == "f":
            poly = []
            pt = []
            for t in parts[1:]:
                fields = t.split("/")
                a = fields[0]
                try:
                    i = int(a)
                except ValueError:
                    i = None
                if i is None or "_" in a:
                    raise MeshFileError(f"{path}: broken OBJ at line {n}: face vertex {t[:30]!r} is "
                                        f"not an integer index")
                if i > 0:
                    if i > MAX_INDEX:
                        raise MeshError(f"{path}: line {n}: face vertex index {i} is out of range "
                                        f"(the file has at most {MAX_INDEX} vertices)")
                    poly.append(i - 1)
                elif i < 0:
                    if -i > nv:
                        raise MeshError(f"{path}: line {n}: relative face index {i} is out of range "
                                        f"(only {nv} vertices defined before it)")
                    poly.append(nv + i)
                else:
                    raise MeshError(f"{path}: line {n}: face vertex index 0 is out of range "
                                    f"(OBJ indices start at 1)")
                pt.append(_texture_index(fields, len(vts)))
            k = len(poly)
            if k >= 3:
                p0, t0 = poly[0], pt[0]
                tris.extend((p0, poly[j], poly[j + 1]) for j in range(1, k - 1))
                tex.extend((t0, pt[j], pt[j + 1]) for j in range(1, k - 1))
                mat.extend([current] * (k - 2))
            elif k:  # a short face: a degenerate triangle, counted and dropped
                tris.append((poly[0], poly[-1], poly[-1]))
                tex.append((pt[0], pt[-1], pt[-1]))
                mat.append(current)
    V = np.array(verts, np.float64).reshape(-1, 3)
    F = np.array(tris, np.int64).reshape(-1, 3)
    vcol = None
    if cols and all(c is not None for c in cols):
        vcol = np.array(cols, np.float64).reshape(-1, 3)
    return {"V": V, "F": F, "vcol": vcol, "vt": np.array(vts, np.float64).reshape(-1, 2), "vt_bad": vt_bad,
            "ft": np.array(tex, np.int64).reshape(-1, 3), "fmat": np.array(mat, np.int64),
            "materials": materials, "mtllibs": mtllibs}


def _texture_index(fields: list, n_vt: int) -> int:
    """0-based texture index of a face corner's ``i/t[/n]`` fields; -1 if it has none (or a
    broken one: texture indices never make a file unreadable)."""
    if len(fields) < 2 or not fields[1]:
        return -1
    try:
        t = int(fields[1])
    except ValueError:
        return -1
    if t > 0:
        return t - 1
    return n_vt + t if -t <= n_vt and t < 0 else -1


def _obj_fast(lines: list, materials_named: bool = True) -> dict | None:
    """The reader's result for the common plain OBJ (``v x y z [r g b]``, ``vt u v``, triangles
    ``f i j k`` / ``f i/t ...`` / ``f i/t/n ...`` with positive indices) in a few numpy calls; None
    if the file has anything else in its v/vt/f lines (:func:`_obj_general` then reads it and
    reports errors by line). ``materials_named``: the text holds "usemtl" or "mtllib" at all."""
    vl = [ln for ln in lines if ln[:2] == "v "]
    fl = [ln for ln in lines if ln[:2] == "f "]
    vtl = [ln for ln in lines if ln[:3] == "vt "]
    n_vf = sum(1 for ln in lines if ln.lstrip()[:1] in ("v", "f") and ln.lstrip()[:2] not in ("vn", "vp"))
    if n_vf != len(vl) + len(fl) + len(vtl):
        return None  # indented, tabs, "vt" without a space, ...: the general reader
    materials, mtllibs, mat_at = [], [], []  # mat_at: (number of faces before it, material)
    if materials_named:  # the file's text mentions usemtl / mtllib
        n_faces = 0
        for ln in lines:
            if ln[:2] == "f ":
                n_faces += 1
            elif ln[:7] == "usemtl ":
                name = " ".join(ln[7:].split("#", 1)[0].split())
                if name not in materials:
                    materials.append(name)
                mat_at.append((n_faces, materials.index(name)))
            elif ln[:7] == "mtllib ":
                mtllibs.extend(ln[7:].split("#", 1)[0].split())
            elif ln.lstrip()[:6] in ("usemtl", "mtllib"):
                return None
    vtxt, ftxt = " ".join(vl), " ".join(fl)
    if "#" in vtxt or any(c in ftxt for c in "#-_+") or "//" in ftxt:
        return None
    vt = vtxt.split()
    # a fixed number of tokens per line: the keywords sit at every per-line stride, nowhere else
    if not vl or len(vt) not in (4 * len(vl), 7 * len(vl)):
        return None
    per_v = len(vt) // len(vl)
    if set(vt[::per_v]) != {"v"}:
        return None
    ft = ftxt.replace("/", " ").split()
    per_f = len(ft) // len(fl) if fl else 4
    if per_f not in (4, 7, 10) or len(ft) != per_f * len(fl) or ("/" in ftxt) != (per_f > 4):
        return None
    if fl and set(ft[::per_f]) != {"f"}:  # every face a triangle (not a quad and a line)
        return None
    if per_f > 4 and ftxt.count("/") != (per_f - 4) // 3 * 3 * len(fl):
        return None
    try:
        vv = np.array(vt, dtype=object).reshape(-1, per_v)[:, 1:].astype(np.float64)
        fa = np.array(ft, dtype=object).reshape(-1, per_f)[:, 1:].astype(np.int64) - 1
        uv = np.zeros((0, 2))
        if vtl:
            vtt = " ".join(vtl).split()
            if len(vtt) not in (3 * len(vtl), 4 * len(vtl)) or set(vtt[::len(vtt) // len(vtl)]) != {"vt"}:
                return None
            uv = np.array(vtt, dtype=object).reshape(len(vtl), -1)[:, 1:3].astype(np.float64)
    except (ValueError, OverflowError):
        return None
    step = (per_f - 1) // 3
    F = fa[:, 0::step]
    if F.size and (F.min() < 0 or F.max() >= MAX_INDEX):
        return None
    tex = fa[:, 1::step] if step > 1 else np.full(F.shape, -1, np.int64)
    fmat = np.full(len(F), -1, np.int64)
    for start, m in mat_at:
        fmat[start:] = m
    return {"V": vv[:, :3], "F": F, "vcol": vv[:, 3:6] if per_v == 7 else None, "vt": uv, "vt_bad": False,
            "ft": tex, "fmat": fmat, "materials": materials, "mtllibs": mtllibs}


def _appearance(path: Path, p: dict) -> Appearance:
    """The colour of a parsed OBJ (rules in the module docstring)."""
    app = Appearance()
    vcol = p["vcol"]
    if vcol is not None and len(vcol):
        if not np.isfinite(vcol).all() or vcol.min() < 0 or vcol.max() > 255:
            app.add_note("vertex colours outside [0, 1] and [0, 255]: not used")
        else:
            app.vertex_colors = vcol / 255.0 if vcol.max() > 1.0 else vcol
    F, ft, vt = p["F"], p["ft"], p["vt"]
    if len(vt) == 0 or len(F) == 0:
        return app
    if (ft < 0).any() or (ft >= len(vt)).any() or p["vt_bad"] or not np.isfinite(vt[ft]).all():
        app.add_note("texture coordinates missing or broken on some triangle corners: texture not used")
        return app
    libs = {}
    for name in p["mtllibs"]:
        for mname, img in read_mtl(path.parent / name).items():
            libs.setdefault(mname, img)
    used = sorted(set(p["fmat"].tolist()))
    if used == [-1]:
        images = {img for img in libs.values()}
    else:
        images = {libs.get(p["materials"][m]) if m >= 0 else None for m in used}
    if not libs:
        app.add_note("texture coordinates but no material file with a texture image (map_Kd): texture not used")
        return app
    if len(images) != 1 or None in images:
        app.add_note(f"the triangles use {len(images - {None})} texture images"
                     f"{' and untextured materials' if None in images else ''}; one is supported: texture not used")
        return app
    try:
        app.texture = read_image(images.pop())
    except ValueError as e:
        app.add_note(f"{e}: texture not used")
        return app
    app.corner_uv = vt[ft]
    return app
