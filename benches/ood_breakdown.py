"""Errors on the out-of-model database broken down by artefact (issue 14).

Reads the per-scan rows of ``facecorr eval registration`` (and, if given, ``facecorr eval
landmarks``) run on a ``bu3dfe-ood`` database, finds each scan's ``"artefacts"`` in its ground
truth, and prints one row per artefact kind (every scan showing it, whatever else it shows), one
for the scans with no artefact at all, and one for all scans: the mean error of the 8 landmarks
the registration used (predicted), the share of scans with all 8 within 10 mm, the region means
(brows, eyes, nose, mouth: mean over the iBUG-68 points of the region, both sides), the dense
correspondence error (mean and median over the scans) and the share of scans with a region point farther than 10 mm.

    python benches/ood_breakdown.py out/ood_reg_test [out/ood_reg_holdout ...] [--landmarks out/ood_lm_test ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

GROUPS = {"brows": ("right_eyebrow", "left_eyebrow"), "eyes": ("right_eye", "left_eye"), "nose": ("nose",),
          "mouth": ("mouth",)}


def _gt_path(scan: str) -> Path:
    p = Path(scan)
    return p.with_name(p.name.rsplit(".", 1)[0] + ".json")


def load_rows(dirs, name):
    rows = []
    for d in dirs:
        f = Path(d) / f"{name}_per_scan.json"
        if not f.is_file():
            raise SystemExit(f"ood_breakdown: error: {f} not found (run facecorr eval first)")
        rows += json.loads(f.read_text())
    for r in rows:
        gt = json.loads(_gt_path(r["scan"]).read_text())
        if "artefacts" not in gt:
            raise SystemExit(f"ood_breakdown: error: {r['scan']}: no 'artefacts' in its ground truth (not a bu3dfe-ood database?)")
        r["_artefacts"] = gt["artefacts"]
        r["_split"] = gt["split"]
    return rows


def row_stats(rows, lm_rows_by_scan):
    ok = [r for r in rows if r["ok"]]
    out = {"n": len(rows), "failed": len(rows) - len(ok)}
    if not ok:
        return out
    lm = np.array([list(r["landmark_errors"].values()) for r in ok])
    out["lm_mean"] = float(lm.mean())
    out["lm_all_within_10"] = float(100.0 * (lm.max(1) < 10.0).mean())
    for g, regs in GROUPS.items():
        vals = np.concatenate([np.asarray(r["regions"].get(k, []), float) for r in ok for k in regs])
        vals = vals[np.isfinite(vals)]
        out[g] = float(vals.mean()) if len(vals) else float("nan")
    out["dense"] = float(np.nanmean([r["dense_mean"] for r in ok]))
    out["dense_median"] = float(np.nanmedian([r["dense_mean"] for r in ok]))
    worst = np.array([max((np.nanmax(np.asarray(v, float)) for v in r["regions"].values() if len(v)), default=np.nan)
                      for r in ok])
    out["region_over_10"] = float(100.0 * (worst > 10.0).mean())
    pred = [lm_rows_by_scan[r["scan"]] for r in ok if r["scan"] in lm_rows_by_scan]
    if pred:
        e = np.array([list(p["errors"].values()) if p["ok"] else [np.inf] * 8 for p in pred])
        fin = e[np.isfinite(e)]
        out["pred_lm_mean"] = float(fin.mean()) if len(fin) else float("nan")
    return out


def breakdown(rows, lm_rows=()):
    from facecorr.synth.artefacts import ARTEFACTS

    by_scan = {r["scan"]: r for r in lm_rows}
    table = [("no artefact", row_stats([r for r in rows if not r["_artefacts"]], by_scan))]
    for kind in ARTEFACTS:
        table.append((kind, row_stats([r for r in rows if kind in r["_artefacts"]], by_scan)))
    table.append(("all", row_stats(rows, by_scan)))
    return table


def markdown(table) -> str:
    head = ("| scans with | n | 8 landmarks mean [mm] | all 8 < 10 mm [%] | brows | eyes | nose | mouth | dense [mm] "
            "| dense, median scan [mm] | a region point > 10 mm [%] |")
    lines = [head, "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in table:
        if "lm_mean" not in s:
            lines.append(f"| {name} | {s['n']} | - | - | - | - | - | - | - | - | - |")
            continue
        lines.append(f"| {name} | {s['n']} | {s['lm_mean']:.2f} | {s['lm_all_within_10']:.1f} | {s['brows']:.2f} | "
                     f"{s['eyes']:.2f} | {s['nose']:.2f} | {s['mouth']:.2f} | {s['dense']:.2f} | {s['dense_median']:.2f} | "
                     f"{s['region_over_10']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("registration", nargs="+", help="folders written by facecorr eval registration --out")
    ap.add_argument("--landmarks", nargs="*", default=[], help="folders written by facecorr eval landmarks --out")
    ap.add_argument("--json", help="also write the table here")
    args = ap.parse_args(argv)
    rows = load_rows(args.registration, "registration")
    lm_rows = load_rows(args.landmarks, "landmarks") if args.landmarks else []
    splits = sorted({r["_split"] for r in rows})
    table = breakdown(rows, lm_rows)
    print(f"{len(rows)} scans ({', '.join(splits)}); region columns: mean error at the region's iBUG-68 points [mm]")
    print(markdown(table))
    if args.json:
        Path(args.json).write_text(json.dumps(dict(table), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
