"""Compare two `facecorr eval registration` runs scan by scan (same database and split): the
median scan's region and dense errors, and the means over the scans both runs got right (every
region point within 30 mm in both), so that a few gross failures do not hide a change.

    python benches/compare_eval_runs.py BEFORE_DIR AFTER_DIR
"""

import argparse
import json
from pathlib import Path

import numpy as np

REGIONS = {"brows": ("right_eyebrow", "left_eyebrow"), "eyes": ("right_eye", "left_eye"), "nose": ("nose",),
           "mouth": ("mouth",)}


def per_scan(path: Path) -> dict:
    rows = json.loads((path / "registration_per_scan.json").read_text())
    out = {}
    for r in rows:
        if not r.get("ok"):
            continue
        reg = r["regions"]
        vals = {k: float(np.mean([np.mean(reg[n]) for n in names if n in reg])) for k, names in REGIONS.items()}
        vals["dense"] = float(r["dense_mean"])
        vals["worst"] = float(max(np.max(v) for v in reg.values()))
        out[r["scan"]] = vals
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    a = ap.parse_args()
    x, y = per_scan(a.before), per_scan(a.after)
    common = sorted(set(x) & set(y))
    good = [s for s in common if x[s]["worst"] <= 30.0 and y[s]["worst"] <= 30.0]
    print(f"{len(common)} scans in both runs, {len(good)} with every region point within 30 mm in both")
    print("| measure | before | after | after / before |\n|---|---|---|---|")
    for k in ("brows", "eyes", "nose", "mouth", "dense"):
        for label, scans, f in (("median scan", common, np.median), ("mean, scans right in both", good, np.mean)):
            b, c = f([x[s][k] for s in scans]), f([y[s][k] for s in scans])
            print(f"| {k}, {label} | {b:.2f} | {c:.2f} | {c / b:.3f} |")


if __name__ == "__main__":
    main()
