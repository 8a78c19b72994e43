"""End-to-end timing of the `facecorr register` command, one scan at a time (issue 5 targets:
expression + shape <= 2 s, the whole command <= 4 s per 50k-vertex scan).

    python benches/register_timing.py DB [--n 7] [--dense 3] [--out out/register_timing]

Times ``facecorr register SCAN -o OUT.ply --json OUT.json`` as a fresh process (start-up, file
I/O and landmark prediction included) on ``--n`` test scans of a synthetic database (one per
subject, cycling through the expressions), and on ``--dense`` scans synthesised at 0.85 mm
sampling (~50k vertices, the issue's size). Prints per scan the vertex count, the command's wall
time and the pipeline's own stage times from the JSON, then the medians and ranges.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

EXPRESSIONS = ("NE", "HA", "SU", "FE", "AN", "DI", "SA")


def pick_scans(db: Path, n: int) -> list[str]:
    from facecorr.synth import load_index

    recs = [r for r in load_index(db) if r["split"] == "test"]
    subjects = sorted({r["subject"] for r in recs})
    out = []
    for i, s in enumerate(subjects[:n]):
        want = EXPRESSIONS[i % len(EXPRESSIONS)]
        r = next((r for r in recs if r["subject"] == s and r["expression"] == want), None)
        out.append((r or next(r for r in recs if r["subject"] == s))["scan"])
    return out


def dense_scans(out: Path, n: int) -> list[str]:
    from facecorr.synth.generate import generate_scan

    paths = []
    for i in range(n):
        rec = generate_scan(out / "dense", subject=60 + i, expression=EXPRESSIONS[(i + 1) % 7], level=4, seed=0,
                            spacing=0.85)
        paths.append(rec["scan"])
    return paths


def time_command(scan: str, out: Path) -> dict:
    stem = Path(scan).stem
    ply, js = out / f"{stem}.ply", out / f"{stem}.json"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "facecorr.cli", "register", scan, "-o", str(ply), "--json", str(js)],
                   check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    t = json.loads(js.read_text())["timings_s"]
    from facecorr.io import load_mesh

    n_v = len(load_mesh(scan).vertices)
    expr_shape = t.get("registration.expression", 0.0) + t.get("registration.shape", 0.0)
    return {"scan": Path(scan).name, "vertices": n_v, "command_s": wall, "pipeline_s": t.get("total", float("nan")),
            "landmarks_s": t.get("landmarks", float("nan")), "expression_shape_s": expr_shape}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("db")
    ap.add_argument("--n", type=int, default=7)
    ap.add_argument("--dense", type=int, default=3)
    ap.add_argument("--out", default="out/register_timing")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"FACECORR_THREADS={os.environ.get('FACECORR_THREADS', '2')}")
    groups = {"test scans": pick_scans(Path(a.db), a.n), "0.85 mm scans": dense_scans(out, a.dense)}
    for name, scans in groups.items():
        rows = [time_command(s, out) for s in scans]
        for r in rows:
            print(f"  {r['scan']:24s} {r['vertices']:6d} vertices: command {r['command_s']:.2f} s, pipeline "
                  f"{r['pipeline_s']:.2f} s (landmarks {r['landmarks_s']:.2f}, expression + shape "
                  f"{r['expression_shape_s']:.2f})", flush=True)
        if rows:
            for key in ("command_s", "pipeline_s", "landmarks_s", "expression_shape_s"):
                v = [r[key] for r in rows]
                print(f"{name}: {key} median {statistics.median(v):.2f}, range {min(v):.2f}-{max(v):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
