"""Colour for the synthetic scans: a smooth skin pattern with an exact value at every true point.

The colour of a point of the head is :func:`skin_colour` of its **material position**: where
the point sits on the ICT model's generic neutral face (mm, model frame). Colour is thus painted
on the skin and moves with it under identity and expression, as a real face's does, and the
true colour of every ground-truth point is known exactly: a scan vertex sampled from ICT
triangle ``tri`` at barycentric ``bary`` has material position ``bary @ neutral[triangles[tri]]``
(:func:`material_positions`); the registered template's vertex ``i`` corresponds to ICT vertex
``template.ict_vertex[i]``, whose true colour is ``skin_colour(neutral[template.ict_vertex[i]])``.

Two ways a scan carries it (``facecorr synth --colour``):

* ``vertex``: per-vertex RGB (uint8) in the PLY, the colour at each vertex's material position;
* ``texture``: an OBJ + MTL + PNG with texture coordinates, like a scanner's textured output.
  The texture is a cylindrical atlas of the neutral face (:func:`texture_atlas`): angle about
  the head's vertical axis -> u, height -> v; every texel holds the colour of the outermost
  neutral surface point it shows. A scan vertex's texture coordinates interpolate the atlas
  coordinates of its ICT triangle's corners with its barycentric weights, so the texture
  reproduces the skin colour wherever that surface is visible in the atlas (in folds hidden from
  the cylinder -- inside the mouth, under the eyelids -- it shows the surface in front). The
  atlas covers the face (``ATLAS_THETA`` = ±2.2 rad about the axis); coordinates beyond are
  clamped, so the back of a raw (uncropped) head gets the edge colours.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..geometry.raster import rasterize
from .model import load_ict

__all__ = ["COLOUR_SOURCES", "skin_colour", "material_positions", "texture_atlas", "scan_texture_coordinates"]

#: Ways a synthetic scan can carry colour.
COLOUR_SOURCES = ("vertex", "texture")

#: Cylinder angle range of the texture atlas (radians about the vertical axis x = 0, z = ATLAS_AXIS_Z).
ATLAS_THETA = 2.2
ATLAS_AXIS_Z = 10.0
#: Atlas height range, mm below / above the nose tip.
ATLAS_BELOW, ATLAS_ABOVE = 140.0, 130.0
ATLAS_SIZE = (1024, 640)  # width, height (texels of ~0.43 mm)


def skin_colour(X: np.ndarray) -> np.ndarray:
    """(N, 3) float64 RGB in [0.15, 0.85] of material positions ``X`` (N, 3) mm.

    Three sinusoids with 90-120 mm wavelengths (one to two periods across a face);
    the steepest slopes are 4.8, 4.0 and 6.7 /255 per mm in R, G and B: smooth, but every region
    has its own colour, and a misplaced vertex shows as a colour error.
    """
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    r = 0.55 + 0.30 * np.sin(2.0 * np.pi * x / 100.0 + 0.4)
    g = 0.50 + 0.30 * np.sin(2.0 * np.pi * y / 120.0 + 1.3)
    b = 0.45 + 0.25 * np.sin(2.0 * np.pi * (x + 0.5 * y + z) / 90.0 + 2.1)
    return np.stack([r, g, b], axis=1)


def material_positions(tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(S, 3) material positions (generic neutral face, mm) of surface points given as ICT
    triangle ids (S,) and barycentric coordinates (S, 3)."""
    model = load_ict()
    corners = model.neutral[model.triangles[np.asarray(tri, dtype=np.int64)]]
    return np.einsum("sk,skd->sd", np.asarray(bary, dtype=np.float64), corners)


def _atlas_coordinates(X: np.ndarray, nose_y: float) -> np.ndarray:
    """(N, 2) texture coordinates (u right, v up, [0, 1] over the atlas) of neutral positions."""
    theta = np.arctan2(X[:, 0], X[:, 2] - ATLAS_AXIS_Z)
    u = (theta + ATLAS_THETA) / (2.0 * ATLAS_THETA)
    v = (X[:, 1] - (nose_y - ATLAS_BELOW)) / (ATLAS_BELOW + ATLAS_ABOVE)
    return np.stack([u, v], axis=1)


@lru_cache(maxsize=1)
def texture_atlas() -> tuple[np.ndarray, np.ndarray]:
    """(image (H, W, 3) uint8, uv (N_ict, 2)): the neutral face's cylindrical colour atlas and
    the texture coordinates of every ICT vertex (module docstring). Texels no surface covers take
    the colour of the nearest covered texel."""
    from scipy.ndimage import distance_transform_edt

    model = load_ict()
    X, T = model.neutral, model.triangles
    uv = _atlas_coordinates(X, float(X[model.landmarks68[30], 1]))
    w, h = ATLAS_SIZE
    px = np.stack([uv[:, 0] * w - 0.5, (1.0 - uv[:, 1]) * h - 0.5], axis=1)  # texel centres at integers
    radius = np.hypot(X[:, 0], X[:, 2] - ATLAS_AXIS_Z)
    theta = np.arctan2(X[:, 0], X[:, 2] - ATLAS_AXIS_Z)
    t = theta[T]
    keep = np.flatnonzero((t.max(1) - t.min(1)) < np.pi)  # not across the seam at the back
    tri, bary, _ = rasterize(px, -radius, T[keep], w, h)
    hit = tri >= 0
    colour = np.zeros((h, w, 3))
    colour[hit] = skin_colour(np.einsum("sk,skd->sd", bary[hit], X[T[keep[tri[hit]]]]))
    _, (ri, ci) = distance_transform_edt(~hit, return_indices=True)
    image = np.round(colour[ri, ci] * 255.0).astype(np.uint8)
    image.setflags(write=False)
    uv.setflags(write=False)
    return image, uv


def scan_texture_coordinates(tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(S, 2) atlas texture coordinates of scan vertices given by ICT triangle and barycentric
    coordinates."""
    _, uv = texture_atlas()
    T = load_ict().triangles
    return np.einsum("sk,skd->sd", np.asarray(bary, dtype=np.float64), uv[T[np.asarray(tri, dtype=np.int64)]])
