"""Z-buffer rasterization of projected triangles (the range-scanner simulation's kernel).

The caller projects the vertices (perspective camera, cylinder around the head, orthographic
view, ...) and passes image coordinates in pixel units plus a depth per vertex; the compiled
kernel returns, per pixel, the nearest covering triangle, its barycentric coordinates and the
interpolated depth.
"""

from __future__ import annotations

import numpy as np

from .. import _core


def rasterize(uv: np.ndarray, depth: np.ndarray, triangles: np.ndarray, width: int, height: int):
    """Rasterize triangles into a ``height x width`` grid, nearest depth wins.

    Parameters
    ----------
    uv : (N, 2) float, pixel coordinates (u = column, v = row); pixel (r, c) has its centre at
        ``(u, v) = (c, r)``. A pixel belongs to a triangle when its centre is inside or on it.
    depth : (N,) float, per-vertex depth (any unit; smaller = nearer), interpolated linearly in
        image space.
    triangles : (M, 3) int, vertex indices.
    width, height : image size in pixels.

    Returns
    -------
    tri : (H, W) int32, the winning triangle's index, -1 where no triangle covers the pixel
        (exact depth ties go to the smaller index).
    bary : (H, W, 3) float64, barycentric coordinates of the pixel centre in that triangle
        (w.r.t. its vertices in ``triangles`` order), 0 where none.
    zbuf : (H, W) float64, interpolated depth, +inf where none.
    """
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    depth = np.ascontiguousarray(depth, dtype=np.float64).reshape(-1)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64)
    if triangles.ndim != 2 or uv.ndim != 2:
        raise ValueError(f"uv must be (N, 2) and triangles (M, 3), got {uv.shape} and {triangles.shape}")
    return _core.rasterize_triangles(uv, depth, triangles, int(width), int(height))
