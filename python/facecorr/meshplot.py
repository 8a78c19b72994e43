"""Small matplotlib renderer for face meshes (painter's algorithm, Lambert shading).

matplotlib's 3-D axes sort whole collections, not triangles, and are slow for ~10k faces; a face
seen from one direction is easy to draw correctly in 2-D instead: rotate, cull back faces, sort
the rest far to near and draw them as one PolyCollection. Used by ``facecorr template --png``.
"""

from __future__ import annotations

import numpy as np


def view_rotation(yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """(3, 3) rotation taking model coordinates (+y up, +z towards the viewer at yaw 0) to view
    coordinates. Positive yaw turns the face to show its left side (+x) to the viewer."""
    y, p = np.radians(yaw_deg), np.radians(pitch_deg)
    ry = np.array([[np.cos(y), 0, -np.sin(y)], [0, 1, 0], [np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    return rx @ ry


def draw_mesh(ax, vertices, faces, face_colors=None, vertex_values=None, cmap="viridis",
              vmin=None, vmax=None, yaw=0.0, pitch=0.0, light=(0.3, 0.4, 1.0), cull=True):
    """Draw a shaded mesh on a 2-D matplotlib axes, seen from (yaw, pitch) degrees.

    Parameters
    ----------
    ax : matplotlib Axes (2-D).
    vertices : (N, 3) float, mm.  faces : (M, 3) int.
    face_colors : (M, 3) RGB in [0, 1], or None.
    vertex_values : (N,) scalars mapped through ``cmap`` (averaged per face), or None (grey).
    yaw, pitch : view angles in degrees (see :func:`view_rotation`).

    Returns
    -------
    (R (3, 3), ScalarMappable or None): the view rotation (to project extra points with
    :func:`project`) and the colour mapping when ``vertex_values`` was given.
    """
    import matplotlib.cm as cm
    import matplotlib.colors as mcolors
    from matplotlib.collections import PolyCollection

    r = view_rotation(yaw, pitch)
    v = np.asarray(vertices, float) @ r.T
    f = np.asarray(faces)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    keep = n[:, 2] > 0 if cull else np.ones(len(f), bool)
    mappable = None
    if vertex_values is not None:
        vals = np.asarray(vertex_values, float)[f].mean(axis=1)
        norm = mcolors.Normalize(vmin=np.min(vals) if vmin is None else vmin,
                                 vmax=np.max(vals) if vmax is None else vmax)
        mappable = cm.ScalarMappable(norm=norm, cmap=cmap)
        base = mappable.to_rgba(vals)[:, :3]
    elif face_colors is not None:
        base = np.asarray(face_colors, float)
    else:
        base = np.full((len(f), 3), 0.8)
    l_dir = np.asarray(light, float) / np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip(np.abs(n @ l_dir), 0, 1)
    col = np.clip(base * shade[:, None], 0, 1)
    idx = np.flatnonzero(keep)
    idx = idx[np.argsort(tri[idx, :, 2].mean(axis=1), kind="stable")]
    pc = PolyCollection(tri[idx, :, :2], facecolors=col[idx], edgecolors=col[idx], linewidths=0.2)
    ax.add_collection(pc)
    lo, hi = v[:, :2].min(0), v[:, :2].max(0)
    pad = 0.03 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.axis("off")
    return r, mappable


def project(points, rotation) -> np.ndarray:
    """(P, 3) model points -> (P, 3) view coordinates (x right, y up, z towards the viewer)."""
    return np.asarray(points, float) @ np.asarray(rotation).T


def visible_points(vertices, faces, points, rotation, tol=0.5) -> np.ndarray:
    """(P,) bool: whether each point (on or near the surface) is unoccluded from the view.

    A point is hidden when a triangle covering its projection lies more than ``tol`` mm in front
    of it (an exact per-point depth test, not a normal test: symmetric points project onto each
    other in a side view).
    """
    v = project(vertices, rotation)
    p = project(points, rotation)
    tri = v[np.asarray(faces)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    out = np.ones(len(p), bool)
    d00 = (b - a)[:, :2]
    d01 = (c - a)[:, :2]
    det = d00[:, 0] * d01[:, 1] - d00[:, 1] * d01[:, 0]
    ok = np.abs(det) > 1e-12
    for i, q in enumerate(p):
        w = q[:2] - a[:, :2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (w[:, 0] * d01[:, 1] - w[:, 1] * d01[:, 0]) / det
            t = (d00[:, 0] * w[:, 1] - d00[:, 1] * w[:, 0]) / det
        inside = ok & (s >= 0) & (t >= 0) & (s + t <= 1)
        depth = a[inside, 2] + s[inside] * (b - a)[inside, 2] + t[inside] * (c - a)[inside, 2]
        out[i] = not (depth > q[2] + tol).any()
    return out
