"""The MHD a perfect registration would get: the true template vertices against the scan.

For each evaluation test scan of a synthetic database, the template vertices are placed where
they truly are (the generator's deformed ICT head at ``template.ict_vertex``, in the scan's pose)
and the paper's MHD (mean distance to the nearest *scan vertex*) is computed, together with the
share of template vertices whose nearest scan vertex lies on the scan's border (template parts
off the scan: beyond the crop, over holes) and the MHD over the other vertices.
Run: python benches/mhd_of_ground_truth.py DB [--every 10]
"""

import argparse
import json

import numpy as np

from facecorr.io import load_mesh
from facecorr.evaluation.runner import select_eval_records
from facecorr.geometry.spatial import KDTree
from facecorr.synth import load_index
from facecorr.synth.generate import model_vertices
from facecorr.template import load_template


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("db")
    ap.add_argument("--every", type=int, default=10, help="every n-th evaluation scan (default 10)")
    args = ap.parse_args()
    t = load_template()
    with open(f"{args.db}/index.json") as fh:
        seed = int(json.load(fh)["seed"])
    recs = select_eval_records(load_index(args.db))[:: args.every]
    rows = []
    for r in recs:
        v, _ = model_vertices(seed, r["subject"], r["expression"], r["level"])
        with np.load(r["dense"]) as d:
            pose = d["pose"]
        truth = v[t.ict_vertex] @ pose[:, :3].T + pose[:, 3]
        mesh = load_mesh(r["scan"], units="mm")
        dist, idx = KDTree(mesh.vertices).query(truth)
        dist = np.asarray(dist)
        border = mesh.is_boundary[np.asarray(idx)]
        rows.append([dist.mean(), dist[~border].mean(), border.mean()])
    rows = np.array(rows)
    print(f"{len(rows)} scans: MHD of the ground truth {rows[:, 0].mean():.3f} mm (std {rows[:, 0].std():.3f}), "
          f"{100 * rows[:, 2].mean():.1f} % of template vertices nearest to the scan border, "
          f"MHD over the others {rows[:, 1].mean():.3f} mm")


if __name__ == "__main__":
    main()
