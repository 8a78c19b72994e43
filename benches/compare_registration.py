"""Registration peer comparison (issue 5): facecorr's register() vs trimesh's nricp_amberg.

Both get the same scans and the same 8 landmarks (the synthetic ground truth by default, or
predicted ones with --landmarks predicted). trimesh.registration.nricp_amberg (Amberg et al.
2007, optimal-step non-rigid ICP) deforms the same template (its rest pose A0, moved onto the scan
by the same landmark similarity our pipeline starts from) with its default schedule
(closest points from a KD-tree over the scan vertices, ``use_faces=False``), landmarks
as ``source_landmarks`` / ``target_positions``. Prints per-region errors at the iBUG-68 points
(paper Table 3 regions), dense correspondence error, MHD and seconds per scan side by side with
the ratio, in one run.

    python benches/compare_registration.py [--db DIR] [--split test] [--every 1] [--n 20]
                                           [--landmarks gt|predicted]

Without --db a database is synthesised once into out/bench_registration_db (bu3dfe preset,
6 subjects, the paper's evaluation subset; its test split has 21 scans).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def synth_db(path: Path) -> Path:
    from facecorr.synth import generate

    if not (path / "index.json").exists():
        print(f"synthesising a test database into {path} ...", flush=True)
        generate(path, preset="bu3dfe", seed=0, subjects=6, subset="eval", workers=2, progress=False)
    return path


def run_peer(template, mesh, lms_arr, transform):
    import trimesh
    from trimesh.registration import nricp_amberg

    from facecorr.registration.alignment import apply_transform

    src = trimesh.Trimesh(apply_transform(transform, template.vertices), template.faces, process=False)
    tgt = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    # use_faces=False: closest points by cKDTree on the scan's vertices (as ours), which also
    # avoids trimesh's optional rtree dependency for proximity queries.
    return np.asarray(nricp_amberg(src, tgt, source_landmarks=np.asarray(template.landmark_ids),
                                   target_positions=lms_arr, use_faces=False))


def measure(template, verts, gt, mesh):
    from facecorr.evaluation import metrics as evaluate

    reg = evaluate.region_errors(verts, gt["ibug68"], template)
    dense = evaluate.dense_error(verts, gt["dense"], template)
    # The paper's MHD averages over every template vertex; the synthetic crop leaves part of the
    # template unscanned (no data there), so also report it over the template vertices of faces
    # that contain a scan vertex according to the dense ground truth ("scanned part").
    face = template.ict_face_to_template_face[np.asarray(gt["dense"]["tri"]).astype(np.int64)]
    covered = np.zeros(template.n_vertices, dtype=bool)
    covered[np.asarray(template.faces)[np.unique(face[face >= 0])].ravel()] = True
    return {"regions": {k: float(np.nanmean(v)) for k, v in reg.items()}, "dense": float(np.mean(dense)),
            "mhd": evaluate.mhd(verts, mesh.vertices), "mhd_scanned": evaluate.mhd(verts[covered], mesh.vertices),
            "scanned_fraction": float(covered.mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", help="synthetic database (default: synthesise out/bench_registration_db)")
    ap.add_argument("--split", default="test", help="the database's split to take scans from (default test;"
                    " an out-of-model database: ood_test or ood_holdout)")
    ap.add_argument("--every", type=int, default=1, help="take every k-th scan of the split (default 1)")
    ap.add_argument("--n", type=int, default=20, help="number of scans (default 20)")
    ap.add_argument("--landmarks", choices=("gt", "predicted"), default="gt")
    ap.add_argument("--out", default="out/bench_registration.json")
    ap.add_argument("--skip-peer", action="store_true", help="only run facecorr")
    args = ap.parse_args(argv)

    from facecorr.evaluation import metrics as evaluate
    from facecorr.io import load_mesh
    from facecorr.names import IBUG68_REGIONS, LANDMARK_NAMES
    from facecorr.registration import register
    from facecorr.registration.alignment import align_landmarks
    from facecorr.synth import load_index
    from facecorr.template import load_template

    db = Path(args.db) if args.db else synth_db(Path("out/bench_registration_db"))
    recs = [r for r in load_index(db) if r["split"] == args.split][:: max(args.every, 1)][: args.n]
    if not recs:
        sys.exit(f"no scans of split {args.split!r} in {db}")
    template = load_template()
    rows = []
    print(f"{len(recs)} {args.split} scans from {db}, landmarks: {args.landmarks}, FACECORR_THREADS={os.environ.get('FACECORR_THREADS', '2')}")
    for i, rec in enumerate(recs):
        mesh = load_mesh(rec["scan"], units="mm")
        gt = evaluate.load_ground_truth(rec["gt"])
        if args.landmarks == "gt":
            lms = {k: np.asarray(gt["landmarks"][k], float) for k in LANDMARK_NAMES}
        else:
            from facecorr.landmarks import predict_landmarks

            lms = {k: np.asarray(v, float) for k, v in predict_landmarks(mesh).positions.items()}
        lms_arr = np.array([lms[k] for k in LANDMARK_NAMES])
        t0 = time.perf_counter()
        ours = register(mesh, lms, template=template)
        t_ours = time.perf_counter() - t0
        row = {"scan": Path(rec["scan"]).name, "ours": measure(template, ours.vertices, gt, mesh)}
        row["ours"]["seconds"] = t_ours
        row["ours"]["seconds_expr_shape"] = ours.timings_s["expression"] + ours.timings_s["shape"]
        if not args.skip_peer:
            transform = align_landmarks(template.vertices[template.landmark_ids], lms_arr, mode="similarity")
            t0 = time.perf_counter()
            try:
                peer_v = run_peer(template, mesh, lms_arr, transform)
                row["peer"] = measure(template, peer_v, gt, mesh)
                row["peer"]["seconds"] = time.perf_counter() - t0
            except Exception as e:  # noqa: BLE001 - a failed peer run is reported, not fatal
                row["peer"] = {"error": f"{type(e).__name__}: {e}"}
        rows.append(row)
        msg = f"[{i + 1}/{len(recs)}] {row['scan']}: ours dense {row['ours']['dense']:.2f} mm {t_ours:.2f} s"
        if "peer" in row and "dense" in row["peer"]:
            msg += f" | nricp_amberg dense {row['peer']['dense']:.2f} mm {row['peer']['seconds']:.2f} s"
        print(msg, flush=True)

    def agg(who, key, region=None):
        vals = [r[who]["regions"][region] if region else r[who][key] for r in rows if who in r and "dense" in r[who]]
        vals = [v for v in vals if np.isfinite(v)]
        return float(np.mean(vals)) if vals else float("nan")

    has_peer = any("peer" in r and "dense" in r["peer"] for r in rows)
    print()
    print("| metric (mean over scans) | facecorr | nricp_amberg | ratio peer/ours |")
    print("|---|---|---|---|")
    lines = [(f"{reg} error [mm]", "regions", reg) for reg in IBUG68_REGIONS]
    lines += [("dense error [mm]", "dense", None), ("MHD, all template vertices [mm]", "mhd", None),
              ("MHD, scanned part of the template [mm]", "mhd_scanned", None), ("seconds per scan", "seconds", None)]
    for label, key, reg in lines:
        a = agg("ours", key, reg)
        b = agg("peer", key, reg) if has_peer else float("nan")
        print(f"| {label} | {a:.3f} | {b:.3f} | {b / a:.2f} |")
    print(f"| expression + shape seconds (ours) | {agg('ours', 'seconds_expr_shape'):.3f} | | |")
    print(f"| scanned fraction of the template | {agg('ours', 'scanned_fraction'):.3f} | | |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(rows, indent=1))
    print(f"per-scan rows: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
