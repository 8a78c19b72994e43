"""Where on the face the registration is wrong: a per-template-vertex map of the dense error.

Registers the evaluation scans of a split (true landmarks, ``--landmarks gt``, or fully automatic)
with the options of ``--variant`` (as in ``benches/variants.py``), and spreads every measured scan
vertex's error vector (registered position of its material point − its noise-free position, mm;
:func:`facecorr.evaluation.metrics.dense_error`) onto the template vertices of its triangle by its
barycentric weights. In the model frame of each scan (its pose undone) the mean vector is split
into its component along the template's normal and the tangential rest. The PNG shows, front view:
the mean error magnitude, the mean tangential magnitude and the mean normal magnitude per vertex
(mm, clamped at ``--vmax``), and the mean tangential vectors as arrows.

    python benches/error_map.py DB --split ood_test --landmarks gt --n 40 -o out/error_map.png [--variant SPEC]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from variants import build_options, parse_variant, select  # noqa: E402


def _one(job):
    rec, pairs, use_gt = job
    from facecorr.evaluation import metrics
    from facecorr.io import load_mesh
    from facecorr.names import LANDMARK_NAMES
    from facecorr.pipeline import correspond
    from facecorr.template import load_template

    t = load_template()
    try:
        mesh = load_mesh(rec["scan"], units="mm")
        gt = metrics.load_ground_truth(rec["gt"])
        lms = {k: gt["landmarks"][k] for k in LANDMARK_NAMES} if use_gt else None
        res = correspond(mesh, landmarks=lms, template=t, options=build_options(pairs))
    except Exception as e:  # noqa: BLE001
        return {"ok": False, "error": str(e)}
    d = gt["dense"]
    tri = np.asarray(d["tri"]).astype(np.int64)
    face = np.where(tri >= 0, t.ict_face_to_template_face[np.maximum(tri, 0)], -1)
    m = face >= 0
    corners = t.faces[face[m]]
    bary = np.asarray(d["bary"], float)[m]
    p = np.einsum("sk,skd->sd", bary, res.vertices[corners])
    r_pose = np.asarray(d["pose"], float)[:, :3]
    err = (p - np.asarray(d["clean"], float)[m]) @ r_pose  # model frame (pose undone)
    n = t.n_vertices
    acc = np.zeros((n, 3))
    wsum = np.zeros(n)
    for k in range(3):
        np.add.at(acc, corners[:, k], bary[:, k:k + 1] * err)
        np.add.at(wsum, corners[:, k], bary[:, k])
    return {"ok": True, "acc": acc, "w": wsum}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("db", type=Path)
    ap.add_argument("--split", default="test")
    ap.add_argument("--landmarks", choices=("gt", "predicted"), default="gt")
    ap.add_argument("--variant", default="base:")
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--artefacts", default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--vmax", type=float, default=5.0)
    ap.add_argument("-o", "--out", type=Path, default=Path("out/error_map.png"))
    a = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facecorr.geometry.mesh import vertex_normals
    from facecorr.render import draw_mesh
    from facecorr.template import load_template
    from facecorr.threads import process_iter

    name, pairs = parse_variant(a.variant)
    recs = select(a.db, a.split, a.artefacts, a.every, a.n)
    rows = list(process_iter(_one, [(r, pairs, a.landmarks == "gt") for r in recs], workers=a.workers,
                             desc="error map", progress=sys.stderr.isatty()))
    ok = [r for r in rows if r["ok"]]
    t = load_template()
    # per scan: mean error vector of each vertex; then the mean over the scans that measured it
    vec = np.zeros((t.n_vertices, 3))
    mag = np.zeros(t.n_vertices)
    cnt = np.zeros(t.n_vertices)
    for r in ok:
        seen = r["w"] > 1e-9
        v = np.zeros_like(r["acc"])
        v[seen] = r["acc"][seen] / r["w"][seen, None]
        vec += v
        mag += np.linalg.norm(v, axis=1)
        cnt += seen
    have = cnt > 0.5 * len(ok)
    mag[~have] = np.nan
    vec[have] /= cnt[have, None]
    mag[have] /= cnt[have]
    nrm = vertex_normals(np.asarray(t.vertices, float), np.asarray(t.faces))
    normal_part = np.einsum("ij,ij->i", vec, nrm)
    tangential = vec - normal_part[:, None] * nrm
    fig, axes = plt.subplots(1, 4, figsize=(20, 6))
    vals = [(mag, "mean |error| per scan [mm]"), (np.linalg.norm(tangential, axis=1), "|mean error|, tangential [mm]"),
            (np.abs(normal_part), "|mean error|, along the normal [mm]")]
    for ax, (v, title) in zip(axes, vals):
        v = np.where(have, v, np.nan)
        sm = draw_mesh(ax, t.vertices, t.faces, values=v, vmin=0.0, vmax=a.vmax, cmap="magma")
        ax.set_title(title)
        fig.colorbar(sm, ax=ax, shrink=0.7)
    ax = axes[3]
    draw_mesh(ax, t.vertices, t.faces)
    sel = np.flatnonzero(have)[::7]
    ax.quiver(t.vertices[sel, 0], t.vertices[sel, 1], tangential[sel, 0], tangential[sel, 1], angles="xy",
              scale_units="xy", scale=0.5, color="blue", width=0.002)
    ax.set_title("mean tangential error (arrows x2)")
    fig.suptitle(f"{a.db.name} {a.split}, {len(ok)} scans, landmarks {a.landmarks}, variant {name}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=80, bbox_inches="tight")
    ids = t.ibug68
    print(f"{len(ok)} scans; mean |error| over measured vertices {np.nanmean(mag[have]):.2f} mm; "
          f"brow points {np.nanmean(mag[ids[17:27][ids[17:27] >= 0]]):.2f}, eye points {np.nanmean(mag[ids[36:48]]):.2f} mm; "
          f"-> {a.out}")
    np.savez_compressed(a.out.with_suffix(".npz"), mean_vector=vec, mean_magnitude=mag, count=cnt)


if __name__ == "__main__":
    main()
