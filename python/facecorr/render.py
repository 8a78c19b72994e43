"""Quick shaded renderings of triangle meshes with matplotlib (no OpenGL needed).

Triangles are projected orthographically, Lambert-shaded and painted far to near
(painter's algorithm) with ``tripcolor``: fast enough for 50k-triangle scans and good enough to
judge a face, a fit or an error map by eye.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .geometry.transforms import kabsch
from .names import LANDMARK_NAMES


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


def plot_registration(mesh, result, path, template, title=None) -> None:
    """PNG of the scan (a Mesh) beside the registered template (a pipeline Result) coloured by
    point-to-plane distance (mm).

    Both are drawn in the template's frame (a rigid fit of the result onto the template's rest
    pose), front view, like the paper's Fig. 11.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io.atomic import atomic_path

    r, t = kabsch(result.vertices, np.asarray(template.vertices, float))
    scan_v = mesh.vertices @ r.T + t
    reg_v = result.vertices @ r.T + t
    # point-to-plane distance from each registered vertex to its nearest scan vertex's tangent plane
    dist, idx = mesh.kdtree.query(result.vertices, k=1)
    n = mesh.vertex_normals[idx]
    p2p = np.abs(np.einsum("ij,ij->i", result.vertices - mesh.vertices[idx], n))
    centre = reg_v.mean(axis=0)
    keep = np.linalg.norm(scan_v - centre, axis=1) < 1.3 * np.linalg.norm(reg_v - centre, axis=1).max()
    fkeep = keep[mesh.faces].all(axis=1)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.5))
    lm = np.array([result.landmarks[k] for k in LANDMARK_NAMES]) @ r.T + t
    draw_mesh(axes[0], scan_v, mesh.faces[fkeep], points=lm)
    axes[0].set_title("scan (red: the landmarks used)")
    sm = draw_mesh(axes[1], reg_v, result.faces, values=p2p, cmap="turbo", vmin=0.0, vmax=1.0)
    axes[1].set_title(f"registered template, MHD {result.mhd:.2f} mm")
    fig.colorbar(sm, ax=axes[1], fraction=0.04, label="point-to-plane distance to scan [mm] (clamped at 1)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def plot_landmarks(rows, path, reference, cols: int = 4) -> None:
    """PNG of scans with their true (green) and predicted (red) landmarks, one panel per row of
    ``evaluate_landmarks`` (needs "scan", "gt", "predicted"), each turned to a front view by a
    rigid fit of its true landmarks onto ``reference`` (8, 3) (the template's landmarks, mm),
    titled with its largest error (mm)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io import load_mesh
    from .io.atomic import atomic_path

    ref = np.asarray(reference, dtype=np.float64)
    n = len(rows)
    nrow = (n + cols - 1) // cols
    fig, axes = plt.subplots(nrow, cols, figsize=(3.2 * cols, 3.6 * nrow), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax, row in zip(axes.ravel(), rows):
        mesh = load_mesh(row["scan"], units="mm")
        gt = json.loads(Path(row["gt"]).read_text())
        truth = np.array([gt["landmarks"][k] for k in LANDMARK_NAMES], float)
        pred = np.asarray(row["predicted"], float)
        r, t = kabsch(truth, ref)
        v = mesh.vertices @ r.T + t
        keep = np.linalg.norm(v - ref.mean(axis=0), axis=1) < 95.0  # the face, not the whole head
        draw_mesh(ax, v, mesh.faces[keep[mesh.faces].all(axis=1)])
        tp, pp = truth @ r.T + t, pred @ r.T + t
        ax.scatter(tp[:, 0], tp[:, 1], s=22, c="lime", edgecolors="black", linewidths=0.5, zorder=6)
        ax.scatter(pp[:, 0], pp[:, 1], s=30, c="red", marker="x", linewidths=1.2, zorder=7)
        name = Path(row["scan"]).stem.replace("_F3D", "")
        ax.set_title(f"{name}: max {max(row['errors'].values()):.1f} mm", fontsize=9)
        ax.axis("off")
    fig.suptitle("landmarks: true (green dots) and predicted (red crosses)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def plot_cumulative(worst, path) -> None:
    """PNG of the paper's Fig. 10: the share of scans (%) whose every evaluation point is under an
    error threshold (mm); ``worst`` (S,) is each scan's largest evaluation-point error, mm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .io.atomic import atomic_path

    worst = np.asarray(worst, dtype=np.float64)
    th = np.linspace(0, max(10.0, float(np.nanmax(worst)) * 1.05), 300)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(th, [100 * (worst <= x).mean() for x in th])
    ax.set_xlabel("error threshold [mm]")
    ax.set_ylabel("scans with every evaluation point under it [%]")
    ax.set_ylim(0, 101)
    ax.grid(alpha=0.3)
    ax.set_title(f"cumulative registration error ({len(worst)} scans)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def plot_shape_modes(mean, components, std, faces, explained, path, *, n_modes: int = 3, sigma: float = 3.0,
                     title: str | None = None) -> None:
    """PNG of a shape model's first modes and its explained variance.

    One row per mode: the mean -/+ ``sigma`` standard deviations of the mode, front and side
    view, coloured by the signed displacement from the mean along the mean's normals (mm; red
    outwards, blue inwards), with the mean itself between them; below, each mode's share of the
    total variance (bars) and the cumulative share (line).

    Parameters
    ----------
    mean : (N, 3) mm in the template's frame (+y up, +z out of the face); components : (K, N, 3)
    orthonormal; std : (K,) standard deviations (mm); faces : (M, 3); explained : (K,) each mode's
    share of the total variance.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .geometry.mesh import vertex_normals
    from .geometry.transforms import view_rotation
    from .io.atomic import atomic_path

    mean = np.asarray(mean, dtype=np.float64)
    comps = np.asarray(components, dtype=np.float64)
    std = np.asarray(std, dtype=np.float64)
    explained = np.asarray(explained, dtype=np.float64)
    k = int(min(n_modes, len(std)))
    normals = vertex_normals(mean, faces)
    views = [("front", view_rotation(0, 0)), ("side", view_rotation(90, 0))]
    height = 2.6 * k + 3.0
    fig = plt.figure(figsize=(15, height))
    gs = fig.add_gridspec(k + 1, 7, height_ratios=[1] * k + [1.15], width_ratios=[1, 1, 1, 0.75, 0.75, 0.75, 0.08],
                          hspace=0.25, wspace=0.02)
    for i in range(k):
        lo, hi = mean - sigma * std[i] * comps[i], mean + sigma * std[i] * comps[i]
        d_hi = np.einsum("ij,ij->i", hi - mean, normals)
        vmax = max(float(np.abs(d_hi).max()), 1e-6)
        col = 0
        for vname, rot in views:
            for label, v, d in ((f"-{sigma:g} sd", lo, -d_hi), ("mean", mean, None), (f"+{sigma:g} sd", hi, d_hi)):
                ax = fig.add_subplot(gs[i, col])
                col += 1
                if d is None:
                    draw_mesh(ax, v, faces, rotation=rot)
                else:
                    sm = draw_mesh(ax, v, faces, rotation=rot, values=d, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
                head = f"mode {i + 1} ({100 * explained[i]:.1f} %) " if col == 1 else f"mode {i + 1} "
                ax.set_title(f"{head}{label} ({vname})" if label != "mean" else f"mean ({vname})", fontsize=9)
        cax = fig.add_subplot(gs[i, 6])
        fig.colorbar(sm, cax=cax, label="mm along the normal")
    ax = fig.add_subplot(gs[k, 1:6])
    shown = min(len(explained), 40)
    x = np.arange(1, shown + 1)
    ax.bar(x, 100 * explained[:shown], color="#7a9cc6", label="each mode")
    cum = 100 * np.cumsum(explained)[:shown]
    ax.plot(x, cum, "o-", color="#c0392b", ms=3.5, label="cumulative")
    for level in (90, 98):
        ax.axhline(level, color="grey", lw=0.6, ls=":")
        ax.text(shown + 0.6, level, f"{level} %", fontsize=7, va="center", color="grey")
    ax.set_xlim(0.3, shown + 2.5)
    ax.set_ylim(0, 102)
    ax.set_xlabel("mode")
    ax.set_ylabel("share of the total variance [%]")
    ax.legend(loc="center right", fontsize=8)
    ax.grid(alpha=0.25)
    if title:
        fig.suptitle(title, fontsize=11, y=fig.subplotpars.top + 0.6 / height)  # ~0.6 in above the grid
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=85, bbox_inches="tight")
    plt.close(fig)
