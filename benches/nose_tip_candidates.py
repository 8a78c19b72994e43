"""Where the nose-tip candidates of the default start search lie against the true tip (issue 14).

For every scan of a split of a synthetic database (with its ground truth), the scan is loaded as
the pipeline loads it (mm, centred, outward), and two sources of nose-tip candidates are checked
(:func:`facecorr.landmarks.protrusion.nose_tip_candidates`, on the pieces the start search keeps):

- the ball protrusion at each ``--radii`` (mm): the rank of the first of its best ``--k`` candidates
  within ``--hit`` mm of the true tip (a miss when none is);
- the point furthest out along the scan's viewing axis (``extreme_axis``): its distance to the tip.

Prints, per split: how many scans the ball finds in its best ``--top`` candidates at each radius,
how many the axis point finds, and how many of the ball's misses (first radius) the axis point
finds. ``--list`` adds one line per scan.

    FACECORR_THREADS=1 python benches/nose_tip_candidates.py /work/db/ood --split ood_test
    FACECORR_THREADS=1 python benches/nose_tip_candidates.py /work/db/bu3dfe_eval --split test --every 5
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

SCAN_SUFFIXES = (".ply", ".obj", ".wrl", ".off", ".stl")


def scans_of(db: Path, split: str, every: int) -> list:
    """[(scan path, ground-truth json path)] of ``split`` in ``db``, every ``every``-th, sorted."""
    out = []
    for gt in sorted(db.glob("*/*.json")):
        meta = json.loads(gt.read_text())
        if meta.get("split") != split or "landmarks" not in meta:
            continue
        scan = next((gt.with_suffix(s) for s in SCAN_SUFFIXES if gt.with_suffix(s).exists()), None)
        if scan is not None:
            out.append((scan, gt))
    return out[::max(1, every)]


def check_scan(scan: Path, gt: Path, radii, k: int, hit: float):
    """(ranks per radius (None = miss), distance of the axis point to the true tip, mm)."""
    from facecorr import load_mesh
    from facecorr.landmarks.predict import PredictOptions
    from facecorr.landmarks.protrusion import nose_tip_candidates

    opts = PredictOptions()
    mesh, offset = load_mesh(scan, units="mm").centred_outward()
    tip = np.asarray(json.loads(gt.read_text())["landmarks"]["nose_tip"], dtype=float) - offset
    areas = mesh.component_areas
    keep = np.isin(mesh.components, np.flatnonzero(areas >= opts.nose_piece_fraction * areas[0]))
    common = dict(keep=keep, median_k=opts.protrusion_median_k, spacing=opts.protrusion_spacing)
    ranks = []
    for r in radii:
        cands = nose_tip_candidates(mesh.vertices, mesh.vertex_normals, k=k, radius=float(r), **common)
        d = [np.linalg.norm(mesh.vertices[v] - tip) for v, _, _ in cands]
        ranks.append(next((i for i, x in enumerate(d) if x < hit), None))
    axis = nose_tip_candidates(mesh.vertices, mesh.vertex_normals, k=0, radius=opts.protrusion_radius,
                               extreme_axis=True, **common)
    return ranks, float(np.linalg.norm(mesh.vertices[axis[-1][0]] - tip)) if axis else float("inf")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("db", type=Path)
    ap.add_argument("--split", default="test")
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--radii", type=float, nargs="+", default=[25.0, 15.0, 12.0])
    ap.add_argument("--k", type=int, default=10, help="ball candidates looked at")
    ap.add_argument("--top", type=int, default=6, help="a ball hit counts within this many candidates")
    ap.add_argument("--hit", type=float, default=12.0, help="a candidate this close to the true tip is a hit, mm")
    ap.add_argument("--list", action="store_true")
    a = ap.parse_args(argv)
    pairs = scans_of(a.db, a.split, a.every)
    if not pairs:
        print(f"no scans of split {a.split!r} with ground truth in {a.db}", file=sys.stderr)
        return 1
    rows = []
    for scan, gt in pairs:
        ranks, d_axis = check_scan(scan, gt, a.radii, a.k, a.hit)
        rows.append((ranks, d_axis))
        if a.list:
            print(scan.stem, "ball ranks", ranks, f"axis point {d_axis:.1f} mm", flush=True)
    found = [[r[0][j] is not None and r[0][j] < a.top for r in rows] for j in range(len(a.radii))]
    axis_ok = [r[1] < a.hit for r in rows]
    print(f"{a.db} {a.split}: {len(rows)} scans; true tip within {a.hit:g} mm of")
    for j, rad in enumerate(a.radii):
        print(f"  one of the {a.top} best ball candidates, radius {rad:g} mm: {sum(found[j])}")
    print(f"  the viewing-axis point: {sum(axis_ok)}")
    missed = [i for i, f in enumerate(found[0]) if not f]
    print(f"  of the {len(missed)} scans the ball misses at {a.radii[0]:g} mm, the axis point finds "
          f"{sum(axis_ok[i] for i in missed)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
