"""A surface's colour at given points: barycentric in per-vertex colours, bilinear in a texture.

A :class:`~facecorr.geometry.mesh.Mesh` has colour from per-vertex RGB (``vertex_colors``) or
from a texture image with per-corner texture coordinates (``face_uv`` + ``texture``).
:func:`colours_at` finds the closest surface point of each query (:mod:`.closest`) and returns
the colour there: per-vertex colours interpolated with the point's barycentric coordinates, or
the texture sampled bilinearly at the interpolated texture coordinates.

Texture conventions (OBJ, VRML, PLY and glTF as trimesh loads it): ``(u, v) = (0, 0)`` is the
image's lower-left corner and ``(1, 1)`` its upper-right; texel ``(row i, column j)`` of an
``H x W`` image (row 0 at the top) has its centre at ``u = (j + 0.5) / W``, ``v = 1 - (i + 0.5) /
H``; coordinates beyond the outer texel centres take the edge texels (clamp to edge; a scanner's
coordinates stay inside [0, 1]).
"""

from __future__ import annotations

import numpy as np

__all__ = ["bilinear", "colours_at", "colours_at_surface_points"]


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of an image at texture coordinates.

    Parameters
    ----------
    image : (H, W, C) uint8 (or float) image, row 0 at the top.
    uv : (Q, 2) float texture coordinates (conventions in the module docstring).

    Returns
    -------
    (Q, C) float64, in [0, 1] for a uint8 image (the image's own scale otherwise).
    """
    img = np.asarray(image)
    scale = 255.0 if img.dtype == np.uint8 else 1.0
    if img.ndim == 2:
        img = img[:, :, None]
    h, w = img.shape[:2]
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    x = np.clip(uv[:, 0] * w - 0.5, 0.0, w - 1.0)
    y = np.clip((1.0 - uv[:, 1]) * h - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    f = img.astype(np.float64)
    top = f[y0, x0] * (1.0 - fx) + f[y0, x1] * fx
    bottom = f[y1, x0] * (1.0 - fx) + f[y1, x1] * fx
    return (top * (1.0 - fy) + bottom * fy) / scale


def colours_at_surface_points(mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Colour of ``mesh`` at surface points given as (triangle, barycentric coordinates).

    Parameters
    ----------
    mesh : Mesh with colour (``mesh.color_source`` "vertex" or "texture").
    face : (Q,) int triangle ids; bary : (Q, 3) barycentric coordinates in ``mesh.faces[face]``.

    Returns
    -------
    (Q, 3) float64 RGB in [0, 1].
    """
    face = np.asarray(face, dtype=np.int64)
    bary = np.asarray(bary, dtype=np.float64).reshape(-1, 3)
    source = mesh.color_source
    if source == "texture":
        uv = np.einsum("qk,qkd->qd", bary, mesh.face_uv[face])
        return bilinear(mesh.texture, uv)[:, :3]
    if source == "vertex":
        c = np.asarray(mesh.vertex_colors, dtype=np.float64)
        return np.einsum("qk,qkd->qd", bary, c[mesh.faces[face]])
    raise ValueError(f"{mesh.source or 'mesh'}: the mesh has no colour (no vertex colours, no texture)")


def colours_at(mesh, points: np.ndarray, *, k: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """The colour of ``mesh`` at the closest surface point of each of ``points``.

    Parameters
    ----------
    mesh : Mesh with colour.
    points : (Q, 3) float, mm, the mesh's frame.
    k : nearest vertices whose triangles are searched (:meth:`facecorr.geometry.closest.TriangleSet.closest`).

    Returns
    -------
    colours : (Q, 3) float64 RGB in [0, 1] (NaN where no triangle was found).
    distance : (Q,) float64, mm, from each point to the surface point sampled.
    """
    face, bary, dist = mesh.triangle_set.closest(points, k=k)
    out = np.full((len(face), 3), np.nan)
    ok = face >= 0
    if ok.any():
        out[ok] = colours_at_surface_points(mesh, face[ok], bary[ok])
    return out, dist
