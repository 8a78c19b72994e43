"""Quick shaded renderings of triangle meshes with matplotlib (no OpenGL needed).

Triangles are projected orthographically, Lambert-shaded and painted far to near
(painter's algorithm) with ``tripcolor``: fast enough for 50k-triangle scans and good enough to
judge a face, a fit or an error map by eye.
"""

from __future__ import annotations

import numpy as np


def kabsch(src: np.ndarray, dst: np.ndarray):
    """Rigid (R, t) minimising sum ||R src_i + t - dst_i||^2 (rows are points, (n, 3))."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cd - r @ cs


def view_rotation(yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> np.ndarray:
    """(3, 3) rotation applied to face-frame points (+y up, +z towards the viewer) before drawing."""
    y, p = np.radians(yaw_deg), np.radians(pitch_deg)
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    return rx @ ry


def draw_mesh(ax, vertices, faces, *, rotation=None, values=None, cmap="viridis", vmin=None,
              vmax=None, base_color=(0.85, 0.78, 0.72), points=None, point_color="red",
              face_colors=None):
    """Draw a shaded mesh on a 2-D matplotlib axis, viewed along -z after ``rotation``.

    Parameters
    ----------
    vertices : (N, 3) float, faces : (M, 3) int
    rotation : (3, 3) applied to the vertices first (default identity).
    values : (N,) per-vertex scalars to colour by (shaded), or None for a plain skin colour.
    points : (K, 3) optional points (same frame) drawn as dots on top.
    face_colors : (M, 3) optional RGB in [0, 1] per triangle (shaded), used when ``values`` is None.
    Returns the ScalarMappable of ``values`` (for a colour bar) or None.
    """
    import matplotlib
    import matplotlib.cm as cm
    import matplotlib.colors as mcolors

    rot = np.eye(3) if rotation is None else np.asarray(rotation)
    v = np.asarray(vertices, float) @ rot.T
    f = np.asarray(faces)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([0.3, 0.4, 1.0])
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.abs(n @ light)
    mappable = None
    if values is None and face_colors is not None:
        rgb = np.asarray(face_colors, float) * shade[:, None]
    elif values is None:
        rgb = np.outer(shade, base_color)
    else:
        fv = np.asarray(values, float)[f].mean(axis=1)
        norm = mcolors.Normalize(vmin=np.nanmin(fv) if vmin is None else vmin,
                                 vmax=np.nanmax(fv) if vmax is None else vmax)
        cmap_ = matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap  # cm.get_cmap is gone in mpl 3.9
        rgb = cmap_(norm(np.nan_to_num(fv)))[:, :3] * shade[:, None]
        mappable = cm.ScalarMappable(norm=norm, cmap=cmap_)
    order = np.argsort(tri[:, :, 2].mean(axis=1))  # far first
    from matplotlib.collections import PolyCollection

    col = np.clip(rgb[order], 0, 1)
    # edges in the face colour close the hairline seams antialiasing leaves between triangles
    pc = PolyCollection(tri[order][:, :, :2], facecolors=col, edgecolors=col, linewidths=0.25)
    ax.add_collection(pc)
    if points is not None:
        p = np.asarray(points, float) @ rot.T
        ax.scatter(p[:, 0], p[:, 1], s=14, c=point_color, zorder=5, edgecolors="white", linewidths=0.5)
    ax.set_xlim(v[:, 0].min(), v[:, 0].max())
    ax.set_ylim(v[:, 1].min(), v[:, 1].max())
    ax.set_aspect("equal")
    ax.axis("off")
    return mappable
