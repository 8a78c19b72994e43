"""CLI: ``facecorr template --json [OUT]`` and ``facecorr template --png OUT.png``.

``--json`` prints (or writes) the template contract (README, "Command line")::

    {"n_vertices": N, "n_faces": M, "units": "mm",
     "frame": "+y up, +z out of the face, subject's right at -x",
     "ibug68": [68 vertex ids or null], "landmarks": {name: vertex id},
     "regions": {"upper": {"count": n, "ids": [...]}, "chin": {...}, "mouth": {...}},
     "boundary": {"outer": [...], "right_eye": [...], "left_eye": [...], "mouth": [...]},
     "blendshapes": [names], "graph_edges": [[i, j], ...], "graph_points": [[x, y, z] x 8]}

``--png`` draws the template coloured by region with the 8 landmarks and the landmark graph
(front, three-quarter and right-side views) and, below, every blendshape at weight 1 coloured
by its displacement magnitude.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ..errors import FacecorrError
from ..io.atomic import atomic_path
from ..names import LANDMARK_NAMES
from ..template import REGION_NAMES, Template, load_template

#: Region colours for drawings (upper, chin, mouth).
REGION_COLORS = np.array([[0.78, 0.80, 0.86], [0.95, 0.62, 0.25], [0.85, 0.25, 0.30]])


def template_contract(t: Template) -> dict:
    """The JSON-able description of the template (see the module docstring)."""
    return {
        "n_vertices": int(t.n_vertices),
        "n_faces": int(len(t.faces)),
        "units": "mm",
        "frame": "+y up, +z out of the face, subject's right at -x",
        "ibug68": [int(i) if i >= 0 else None for i in t.ibug68],
        "landmarks": t.landmarks,
        "regions": {name: {"count": int(len(ids)), "ids": ids.tolist()}
                    for name, ids in ((n, t.region_ids(n)) for n in REGION_NAMES)},
        "boundary": {name: loop.tolist() for name, loop in t.boundary_loops.items()},
        "blendshapes": list(t.blendshape_names),
        "graph_edges": t.graph_edges.tolist(),
        "graph_points": np.round(t.graph_points, 4).tolist(),
    }


def _landmark_overlay(ax, t: Template, rotation):
    p = t.graph_points @ rotation.T
    from ..template import visible_points  # the builder (scipy): only when drawing, not at every command's start

    visible = visible_points(t.vertices, t.faces, t.graph_points, rotation)
    for i, j in t.graph_edges:
        if visible[i] and visible[j]:
            ax.plot(p[[i, j], 0], p[[i, j], 1], "-", color="#1060c0", lw=1.2, zorder=3)
    ax.scatter(p[visible, 0], p[visible, 1], s=22, c="#ffee00", edgecolors="k", linewidths=0.7, zorder=4)
    for k in np.flatnonzero(visible):
        ax.annotate(str(k + 1), p[k, :2], xytext=(3, 3), textcoords="offset points", fontsize=8,
                    color="k", zorder=5)


def draw_template_png(out_path: str | Path, t: Template | None = None, dpi: int = 90) -> None:
    """Write the template drawing (regions, landmarks, graph; blendshapes) to ``out_path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from ..geometry.transforms import view_rotation
    from ..render import draw_mesh

    t = t or load_template()
    # mixed triangles get the mean of their corners' colours: a soft edge instead of a saw-tooth
    face_colors = REGION_COLORS[t.regions[t.faces]].mean(axis=1)

    k = t.n_blendshapes
    ncol = 5
    nrow_b = -(-k // ncol)
    fig = plt.figure(figsize=(3.2 * ncol, 4.6 + 3.3 * nrow_b))
    gs = fig.add_gridspec(1 + nrow_b, ncol, height_ratios=[1.45] + [1] * nrow_b, hspace=0.15, wspace=0.02)
    # render.view_rotation: positive yaw turns the subject's right (-x) towards the viewer.
    views = [("front", 0, 0), ("three-quarter (subject's left)", -35, 0), ("subject's right side", 90, 0)]
    top = gs[0, :].subgridspec(1, 3, wspace=0.02)
    for c, (title, yaw, pitch) in enumerate(views):
        ax = fig.add_subplot(top[0, c])
        rot = view_rotation(yaw, pitch)
        draw_mesh(ax, t.vertices, t.faces, rotation=rot, face_colors=face_colors)
        _landmark_overlay(ax, t, rot)
        ax.set_title(title, fontsize=10)
    fig.legend(handles=[Patch(color=REGION_COLORS[i], label=f"{n} ({(t.regions == i).sum()} v)")
                        for i, n in enumerate(REGION_NAMES)]
               + [Patch(color="#ffee00", label="landmarks: " + ", ".join(
                   f"{i + 1} {n}" for i, n in enumerate(LANDMARK_NAMES)))],
               loc="upper center", ncol=2, fontsize=8, frameon=False, bbox_to_anchor=(0.5, 0.975))
    for b in range(k):
        ax = fig.add_subplot(gs[1 + b // ncol, b % ncol])
        mag = np.linalg.norm(t.blendshapes[b], axis=1)
        draw_mesh(ax, t.vertices + t.blendshapes[b], t.faces, rotation=view_rotation(-25, 0),
                  values=mag, cmap="YlOrRd", vmin=0, vmax=mag.max())
        ax.set_title(f"{t.blendshape_names[b]} (max {mag.max():.1f} mm)", fontsize=9)
    fig.suptitle(f"facecorr template: {t.n_vertices} vertices, {len(t.faces)} faces, "
                 f"{k} blendshapes (below: each at weight 1, colour = |A_k| from 0 to its max)",
                 y=1.0, fontsize=11)
    fig.savefig(out_path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)


def cmd_template(args) -> int:
    t = load_template()
    did = False
    if args.png is not None and Path(args.png).suffix.lower() != ".png":
        raise FacecorrError(f"--png expects a .png path, got {args.png!r}")
    if args.json is not None:
        text = json.dumps(template_contract(t))
        if args.json == "-":
            sys.stdout.write(text + "\n")
        else:
            with atomic_path(args.json) as tmp:
                tmp.write_text(text + "\n")
        did = True
    if args.png is not None:
        with atomic_path(args.png) as tmp:
            draw_template_png(tmp, t)
        did = True
    if not did:
        raise FacecorrError("facecorr template: give --json and/or --png OUT.png")
    return 0


def add_commands(subparsers) -> None:
    """Register ``facecorr template`` on an argparse subparsers object."""
    p = subparsers.add_parser("template", help="describe or draw the blendshape template",
                              description=__doc__.splitlines()[0])
    p.add_argument("--json", nargs="?", const="-", default=None, metavar="OUT",
                   help="print the template contract as JSON (to OUT if given)")
    p.add_argument("--png", metavar="OUT.png", help="draw regions, landmarks, graph and blendshapes")
    p.set_defaults(func=cmd_template)

