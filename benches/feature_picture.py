"""Front view of one eye or the nose of a synthetic scan, registered with and without its search
(the eye or nose search, issue 14).

Each panel shades the scan by its (smoothed) normals around the feature and draws its true iBUG-68
points (green: an eye's contour; the nose's tip and base) and the registered template's (red),
fully automatic::

    python benches/feature_picture.py /work/db/ood/F0001/F0001_NE00_F3D.ply benches/figures/eye_search.png [--feature left_eye]
    python benches/feature_picture.py /work/db/ood/F0010/F0010_AN04_F3D.ply benches/figures/nose_search.png --feature nose

The scan's ground-truth JSON (same stem) gives the true contour.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scan", type=Path)
    ap.add_argument("png", type=Path)
    ap.add_argument("--feature", choices=("right_eye", "left_eye", "nose"), default="right_eye",
                    help="the subject's right or left eye, or the nose")
    a = ap.parse_args(argv)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh

    from facecorr.evaluation import metrics
    from facecorr.geometry.transforms import kabsch
    from facecorr.io import load_mesh
    from facecorr.names import LANDMARK_NAMES
    from facecorr.pipeline.correspond import CorrespondOptions, correspond
    from facecorr.registration import RegisterOptions
    from facecorr.template import load_template

    tpl = load_template()
    gt = metrics.load_ground_truth(a.scan.with_suffix(".json"))
    mesh = load_mesh(a.scan, units="mm")
    # the feature's iBUG-68 points, the polyline drawn through them, and its search option
    eye = {"right_eye": list(range(36, 42)), "left_eye": list(range(42, 48)), "nose": list(range(30, 36))}[a.feature]
    loop = [0, 1, 2, 3, 4, 5, 0] if a.feature != "nose" else [1, 2, 3, 4, 5, 0, 1]
    option, what = ("nose_search", "nose search") if a.feature == "nose" else ("eye_search", "eye search")
    # the picture's frame: the true 8 landmarks on the template's (front view, y up)
    g = np.array([gt["landmarks"][n] for n in LANDMARK_NAMES])
    r, s, t = kabsch(g, np.asarray(tpl.vertices)[tpl.landmark_ids], with_scale=True)
    to_front = lambda x: s * np.asarray(x, float) @ r.T + t  # noqa: E731
    sv = to_front(mesh.vertices)
    smooth = trimesh.Trimesh(sv, mesh.faces, process=False)
    trimesh.smoothing.filter_taubin(smooth, iterations=10)
    # the nose's sides face away from a light from above: light it from the front
    light = np.array([0.3, 0.5, 0.8]) if a.feature != "nose" else np.array([0.15, 0.25, 1.0])
    light = light / np.linalg.norm(light)
    shade = smooth.vertex_normals @ light
    true = to_front(gt["ibug68"][eye])
    lo, hi = np.nanmin(true, axis=0) - 8.0, np.nanmax(true, axis=0) + 8.0
    inside = np.all((sv[:, :2] > lo[:2]) & (sv[:, :2] < hi[:2]), axis=1)
    faces = mesh.faces[inside[mesh.faces].all(axis=1)]

    fig, axes = plt.subplots(1, 2, figsize=(13, 3.9))
    for ax, (title, search) in zip(axes, ((f"without the {what}", None), (f"with the {what} (default)", "default"))):
        opts = CorrespondOptions() if search else CorrespondOptions(register=replace(RegisterOptions(), **{option: None}))
        res = correspond(mesh, options=opts)
        reg = to_front(res.vertices[np.asarray(tpl.ibug68)[eye]])
        err = np.nanmean(np.linalg.norm(res.vertices[np.asarray(tpl.ibug68)[eye]] - gt["ibug68"][eye], axis=1))
        ax.tripcolor(sv[:, 0], sv[:, 1], faces, facecolors=shade[faces].mean(axis=1), cmap="gray", vmin=0.3, vmax=1.0)
        ax.plot(true[loop, 0], true[loop, 1], "g.-", lw=2, label="true points")
        ax.plot(reg[loop, 0], reg[loop, 1], "r.-", lw=2, label="registered template")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_title(f"{title}: points {err:.2f} mm off", fontsize=10)
        ax.legend(loc="lower right", fontsize=8)
    name = {"right_eye": "the subject's right eye", "left_eye": "the subject's left eye", "nose": "the lower nose"}[a.feature]
    fig.suptitle(f"{a.scan.name}, {name} (front view, mm)", fontsize=11)
    a.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.png, dpi=80, bbox_inches="tight")
    print(f"wrote {a.png}")


if __name__ == "__main__":
    main()
