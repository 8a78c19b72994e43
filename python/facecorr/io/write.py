"""Writing meshes: :func:`save_mesh` and the exact PLY / OBJ / OFF / VRML byte writers.

PLY (binary, float64), OBJ and OFF (text, shortest round-trip ``repr`` digits) and VRML
(``%.17g``) are written by our own writers, so a saved mesh loads back bit for bit; STL and GLB
(float32 by format) go through trimesh. Every file is written atomically
(:func:`facecorr.io.atomic.write_bytes_atomic`): nothing is left on error.

Per-vertex colours (``colors=`` or a Mesh's ``vertex_colors``) are written as uchar ``red green
blue [alpha]`` in PLY, ``v x y z r g b`` (r, g, b in [0, 1]) in OBJ, a ``Color`` node in VRML and
vertex colours in GLB; OFF and STL files get no colour. A Mesh with a texture saved as OBJ is
written as three files, ``NAME.obj`` + ``NAME.mtl`` + ``NAME.png`` (all or none); in the other
formats its texture is not written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import MeshError, MeshFileError
from ..geometry.mesh import Mesh
from .atomic import atomic_paths, write_bytes_atomic
from .load import format_of, one_line, unit_factor

__all__ = ["save_mesh"]


def _ply_bytes(V: np.ndarray, F: np.ndarray, colors: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY with float64 vertices (exact), optional uchar colours (N, 3 or 4)
    and int32 triangle indices."""
    props = "property double x\nproperty double y\nproperty double z\n"
    fields = [("xyz", "<f8", (3,))]
    if colors is not None:
        names = ("red", "green", "blue", "alpha")[:colors.shape[1]]
        props += "".join(f"property uchar {n}\n" for n in names)
        fields.append(("rgba", "u1", (colors.shape[1],)))
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by facecorr\n"
              f"element vertex {len(V)}\n{props}"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.empty(len(V), dtype=fields)
    verts["xyz"] = V
    if colors is not None:
        verts["rgba"] = colors
    faces = np.empty(len(F), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    faces["n"] = 3
    faces["idx"] = F
    return header.encode("ascii") + verts.tobytes() + faces.tobytes()


def _xyz_lines(V: np.ndarray, prefix: str = "", colors: np.ndarray | None = None) -> str:
    """One ``prefix x y z [r g b]`` line per row of V (N, 3), shortest round-trip digits; colours
    (N, >= 3) uint8 written as r / 255 with 6 significant digits (reads back to the same byte)."""
    if colors is None:
        return "".join(f"{prefix}{x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
    c = (colors[:, :3] / 255.0).tolist()
    return "".join(f"{prefix}{x!r} {y!r} {z!r} {r:.6g} {g:.6g} {b:.6g}\n" for (x, y, z), (r, g, b) in zip(V.tolist(), c))


def _obj_text(V: np.ndarray, F: np.ndarray, colors: np.ndarray | None = None, uv: np.ndarray | None = None,
              mtl: str | None = None) -> str:
    """Wavefront OBJ, coordinates written exactly (shortest round-trip repr), 1-based faces; with
    ``uv`` (M, 3, 2) ``vt`` lines (one per vertex when every corner of a vertex has the same
    coordinates, else one per triangle corner) and ``f v/t ...``, material file ``mtl``."""
    head = "# written by facecorr\n"
    if uv is None:
        faces = "".join(f"f {a} {b} {c}\n" for a, b, c in (F + 1).tolist())
        return head + _xyz_lines(V, "v ", colors) + faces
    head += f"mtllib {mtl}\n"
    per_vertex = np.zeros((len(V), 2))
    per_vertex[F.ravel()] = uv.reshape(-1, 2)
    if np.array_equal(per_vertex[F], uv):  # no seams: one vt per vertex, as the vertices
        vts = "".join(f"vt {u!r} {v!r}\n" for u, v in per_vertex.tolist())
        t = F + 1
    else:  # one vt per triangle corner
        vts = "".join(f"vt {u!r} {v!r}\n" for u, v in uv.reshape(-1, 2).tolist())
        t = np.arange(1, 3 * len(F) + 1).reshape(-1, 3)
    faces = "".join(f"f {a}/{ta} {b}/{tb} {c}/{tc}\n" for (a, b, c), (ta, tb, tc) in zip((F + 1).tolist(), t.tolist()))
    return head + _xyz_lines(V, "v ", colors) + vts + "usemtl texture\n" + faces


def _off_text(V: np.ndarray, F: np.ndarray) -> str:
    """OFF, coordinates written exactly (shortest round-trip repr)."""
    faces = "".join(f"3 {a} {b} {c}\n" for a, b, c in F.tolist())
    return f"OFF\n{len(V)} {len(F)} 0\n" + _xyz_lines(V) + faces


def _wrl_text(V: np.ndarray, F: np.ndarray, colors: np.ndarray | None = None) -> str:
    """VRML 2.0 text of one Shape with an IndexedFaceSet (coordinates written exactly, %.17g),
    with a per-vertex ``Color`` node when ``colors`` (N, >= 3) uint8 are given."""
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    pts = ",\n".join(f"{x:.17g} {y:.17g} {z:.17g}" for x, y, z in V.tolist())
    idx = ",\n".join(f"{a}, {b}, {c}, -1" for a, b, c in F.tolist())
    col = ""
    if colors is not None:
        rgb = ",\n".join(f"{r:.6g} {g:.6g} {b:.6g}" for r, g, b in (colors[:, :3] / 255.0).tolist())
        col = f"  color Color {{\n   color [\n{rgb}\n   ]\n  }}\n"
    return ("#VRML V2.0 utf8\n# written by facecorr\n"
            "Shape {\n geometry IndexedFaceSet {\n  coord Coordinate {\n   point [\n"
            f"{pts}\n   ]\n  }}\n{col}  coordIndex [\n{idx}\n  ]\n }}\n}}\n")


def _colour_bytes(colors, n: int) -> np.ndarray | None:
    """(n, 3 or 4) uint8 of ``colors``: uint8 as given, floats in [0, 1] scaled by 255 and
    rounded; MeshError on a wrong shape or range."""
    if colors is None:
        return None
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise MeshError(f"colors must have shape ({n}, 3) or ({n}, 4), got {c.shape}")
    if c.dtype == np.uint8:
        return np.ascontiguousarray(c)
    c = np.asarray(c, dtype=np.float64)
    if not np.isfinite(c).all() or c.min() < 0 or c.max() > 1:
        raise MeshError("colors must be uint8, or floats in [0, 1] without NaN")
    return np.round(c * 255.0).astype(np.uint8)


def save_mesh(path, mesh_or_VF, units: str | None = None, *, colors=None) -> None:
    """Write a mesh: PLY (binary, float64), OBJ, OFF and WRL (text, exact round-trip digits) by our
    writers; STL and GLB (float32 by format) through trimesh.

    Parameters
    ----------
    path : str or Path, the format is taken from the extension.
    mesh_or_VF : Mesh, or a pair (V (N, 3) mm, F (M, 3) int).
    units : "mm", "cm", "m" or None
        Units to write in. None: the mesh's own source units (``mesh.units``; mm for a (V, F) pair),
        so a loaded scan goes back in its own units.
    colors : optional (N, 3) or (N, 4) per-vertex colours, uint8 or floats in [0, 1] (RGB or
        RGBA; alpha is written to PLY only). Default: the Mesh's ``vertex_colors``. Where they go
        in each format: the module docstring (a textured Mesh as OBJ writes OBJ + MTL + PNG).

    Raises
    ------
    MeshFileError for an unknown format or an unwritable path; MeshError for an invalid mesh or
    colours; UnitsError for unknown units. Nothing is written on error.
    """
    path = Path(path)
    fmt = format_of(path)
    if isinstance(mesh_or_VF, Mesh):
        mesh = mesh_or_VF
    else:
        try:
            V, F = mesh_or_VF
        except (TypeError, ValueError):
            raise MeshError("save_mesh needs a Mesh or a (vertices, faces) pair") from None
        mesh = Mesh(V, F)
    factor = unit_factor(units if units is not None else mesh.units)
    V = mesh.vertices / factor
    F = mesh.faces
    rgb = _colour_bytes(colors if colors is not None else mesh.vertex_colors, len(V))
    if fmt == "obj" and mesh.texture is not None:
        _save_textured_obj(path, V, F, rgb, mesh.face_uv, mesh.texture)
        return
    if fmt == "wrl":
        data = _wrl_text(V, F, rgb).encode("ascii")
    elif fmt == "ply":
        data = _ply_bytes(V, F, rgb)
    elif fmt == "obj":
        data = _obj_text(V, F, rgb).encode("ascii")
    elif fmt == "off":
        data = _off_text(V, F).encode("ascii")
    else:
        import trimesh

        tm = trimesh.Trimesh(vertices=V, faces=F, process=False, validate=False,
                             vertex_colors=None if rgb is None or fmt == "stl" else rgb)
        try:
            data = tm.export(file_type=fmt)
        except Exception as e:  # noqa: BLE001
            raise MeshFileError(f"{path}: cannot export {fmt.upper()} ({one_line(e)})") from None
        if isinstance(data, str):
            data = data.encode("utf-8")
    write_bytes_atomic(path, data)


def _save_textured_obj(path: Path, V, F, rgb, face_uv: np.ndarray, texture: np.ndarray) -> None:
    """``path`` (OBJ with one ``vt`` per corner) + ``path.mtl`` + ``path.png``, as a group."""
    from PIL import Image

    mtl, png = path.with_suffix(".mtl"), path.with_suffix(".png")
    with atomic_paths(path, mtl, png) as (t_obj, t_mtl, t_png):
        Image.fromarray(np.asarray(texture, dtype=np.uint8)).save(t_png, format="PNG")
        t_mtl.write_text(f"# written by facecorr\nnewmtl texture\nKd 1 1 1\nmap_Kd {png.name}\n")
        t_obj.write_text(_obj_text(V, F, rgb, face_uv, mtl.name))
