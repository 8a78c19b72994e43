"""Picture of the mirror check (facecorr.pipeline.mirror): scans registered without it and with it.

Each column is one scan, seen from the front in its true face frame (its synthetic pose undone):
the scan's vertices in grey, the registered template's 68 iBUG points without the check (red)
and with it (green), the true points (black rings), and the mid-plane each registration put the
face's midline in (dashed red / green). The title gives the dense error of both.

    python benches/mirror_picture.py /work/db/ood/M0008/M0008_HA04_F3D.ply ... -o benches/figures/mirror_check.png
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scans", nargs="+", type=Path, help="scans of a `facecorr synth` database")
    ap.add_argument("-o", "--out", type=Path, required=True)
    a = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facecorr.evaluation.metrics import dense_error, load_ground_truth
    from facecorr.geometry.transforms import kabsch
    from facecorr.io import load_mesh
    from facecorr.pipeline import correspond
    from facecorr.pipeline.correspond import CorrespondOptions
    from facecorr.template import load_template

    template = load_template()
    fig, axes = plt.subplots(1, len(a.scans), figsize=(4.2 * len(a.scans), 5.0), squeeze=False)
    for ax, path in zip(axes[0], a.scans):
        gt = load_ground_truth(path.with_suffix(".json"))
        pose = np.load(path.with_name(path.stem + "_dense.npz"))["pose"]
        mesh = load_mesh(path)
        runs = []
        for opts in (replace(CorrespondOptions(), mirror=None), CorrespondOptions()):
            r = correspond(mesh, options=opts)
            runs.append((r, float(np.mean(dense_error(r.vertices, gt["dense"])))))
        to_face = lambda x: (np.asarray(x, float) - pose[:, 3]) @ pose[:, :3]  # scan -> model frame
        v = to_face(mesh.vertices)
        step = max(1, len(v) // 20000)
        ax.scatter(v[::step, 0], v[::step, 1], s=0.3, c="0.75", rasterized=True)
        ib = to_face(gt["ibug68"])
        ax.scatter(ib[:, 0], ib[:, 1], s=14, facecolors="none", edgecolors="k", linewidths=0.6, label="true")
        for (r, _), colour, name in zip(runs, ("tab:red", "tab:green"), ("without", "with")):
            p = to_face(r.ibug68)
            ax.scatter(p[:, 0], p[:, 1], s=6, c=colour, label=f"{name} the check")
            rot = kabsch(np.asarray(template.vertices), to_face(r.vertices), with_scale=True)[0]
            tip = to_face(r.landmarks_registered["nose_tip"])
            up = rot[:2, 1] / np.linalg.norm(rot[:2, 1])  # the fitted template's up axis, front view
            line = np.array([tip[:2] - 70 * up, tip[:2] + 70 * up])
            ax.plot(line[:, 0], line[:, 1], "--", c=colour, lw=1)
        ax.set_title(f"{path.stem.replace('_F3D', '')}\ndense {runs[0][1]:.1f} mm without, {runs[1][1]:.1f} mm with",
                     fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlim(-90, 90)
        ax.set_ylim(-110, 90)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0][0].legend(loc="lower left", fontsize=7, markerscale=2)
    fig.suptitle("Mirror check: fits turned off the scan's symmetry plane, registered again", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
