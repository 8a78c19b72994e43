"""``facecorr eval registration``: the paper's Table 3, MHD, dense error and Fig. 10 on a database.

Runs the pipeline on the evaluation scans of a synthetic database (test split, neutral + the six
expressions at the highest level, as in the paper), in a process pool with a progress bar, and
writes ``registration_table.md``, ``registration_table.csv``, ``registration_per_scan.json`` and
``cumulative.png`` (share of scans whose every evaluation point is under a threshold).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..names import LANDMARK_NAMES


def _eval_one(job):
    """Worker: register one scan and measure it against its ground truth; never raises."""
    rec, use_gt_landmarks = job
    from . import metrics as evaluate
    from ..io import load_mesh
    from ..pipeline import correspond
    from ..template import load_template

    t0 = time.perf_counter()
    try:
        template = load_template()
        mesh = load_mesh(rec["scan"], units="mm")
        gt = evaluate.load_ground_truth(rec["gt"])
        lms = {k: gt["landmarks"][k] for k in LANDMARK_NAMES} if use_gt_landmarks else None
        res = correspond(mesh, landmarks=lms, template=template)
        regions = evaluate.region_errors(res.vertices, gt["ibug68"], template)
        dense = evaluate.dense_error(res.vertices, gt["dense"], template)
        lm_err = {k: float(np.linalg.norm(np.asarray(res.landmarks[k]) - gt["landmarks"][k])) for k in LANDMARK_NAMES}
        reg_err = {k: float(np.linalg.norm(np.asarray(res.landmarks_registered[k]) - gt["landmarks"][k]))
                   for k in LANDMARK_NAMES}
        return {
            "scan": rec["scan"], "ok": True,
            "regions": {k: np.asarray(v, float).tolist() for k, v in regions.items()},
            "dense_mean": float(np.mean(dense)) if len(dense) else float("nan"),
            "mhd": float(res.mhd), "landmark_errors": lm_err, "registered_landmark_errors": reg_err,
            "seconds": time.perf_counter() - t0, "timings_s": res.timings_s,
        }
    except Exception as e:  # noqa: BLE001 - a failed scan is a result too
        return {"scan": rec["scan"], "ok": False, "error": f"{type(e).__name__}: {e}"}


def write_reports(rows, out_dir: Path) -> str:
    """Write the Markdown/CSV tables, the per-scan JSON and the cumulative PNG; return the Markdown."""
    from .runner import write_report
    from ..render import plot_cumulative
    from .metrics import format_region_table, summarize_regions

    ok = [r for r in rows if r["ok"]]
    table = summarize_regions([{k: np.asarray(v, float) for k, v in r["regions"].items()} for r in ok])
    lines = [format_region_table(table).rstrip("\n")]
    mhd = np.array([r["mhd"] for r in ok]) if ok else np.array([np.nan])
    dense = np.array([r["dense_mean"] for r in ok]) if ok else np.array([np.nan])
    secs = np.array([r["seconds"] for r in ok]) if ok else np.array([np.nan])
    lines += ["", f"MHD mean / std / max: {mhd.mean():.3f} / {mhd.std():.3f} / {mhd.max():.3f} mm; "
              f"dense correspondence error (mean over scans of the per-scan mean): {dense.mean():.3f} mm; "
              f"median seconds per scan: {np.median(secs):.2f}; scans: {len(ok)} ok, {len(rows) - len(ok)} failed."]
    md = "\n".join(lines) + "\n"
    write_report(out_dir, "registration", md, table, "region,mean,std,max,T10,T20,T30,n_scans",
                 "{region},{mean:.4f},{std:.4f},{max:.4f},{T10:.2f},{T20:.2f},{T30:.2f},{n_scans}", rows)
    if ok:  # Fig. 10: cumulative share of scans whose every evaluation point is under the threshold
        worst = np.array([max(np.nanmax(np.asarray(v, float)) for v in r["regions"].values()) for r in ok])
        plot_cumulative(worst, out_dir / "cumulative.png")
    return md


def evaluate_registration(db_dir, out_dir, *, use_gt_landmarks=False, workers=2, limit=None, split="test",
                          progress=True, on_row=None, quiet=False):
    """Run and report the registration evaluation; returns the per-scan rows.

    ``progress``: the bar; ``on_row``: called with each per-scan row as it comes; ``quiet``: do not
    print the table (it is in ``out_dir``)."""
    from .runner import run_on_eval_scans

    rows = run_on_eval_scans(db_dir, _eval_one, lambda k, r: (r, use_gt_landmarks), workers=workers, limit=limit,
                             split=split, progress=progress, on_row=on_row)
    md = write_reports(rows, Path(out_dir))
    if not quiet:
        print(md)
    return rows
