"""Where one scan's time goes (issue 17): ``load_mesh`` + ``correspond`` on N scans in one process,
per-stage medians from the results' ``timings_s``; meant to be run under a sampling profiler too.

    FACECORR_THREADS=1 python benches/profile_scans.py FOLDER [--n 6]
    FACECORR_THREADS=1 py-spy record --idle -r 200 -f flamegraph -o benches/profile/NAME.svg -- \\
        python benches/profile_scans.py FOLDER --n 6

FOLDER is any folder of scans (e.g. the one ``benches/throughput.py`` synthesises). One thread, as
a batch worker runs; ``--idle`` makes py-spy count the time the main thread waits for the Rust
kernels' pool, which is otherwise missing from the graph.
"""

from __future__ import annotations

import argparse
import collections
import statistics
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--n", type=int, default=6)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    from facecorr.io import load_mesh
    from facecorr.pipeline import correspond
    from facecorr.template import load_template

    load_template()
    startup = time.perf_counter() - t0
    files = sorted(p for p in a.folder.rglob("*") if p.suffix.lower() in (".ply", ".obj", ".wrl", ".off", ".stl"))
    files = [p for p in files if not p.stem.endswith("_dense")][: a.n]
    acc = collections.defaultdict(list)

    def walk(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            elif isinstance(v, (int, float)):
                acc[prefix + k].append(float(v))

    for p in files:
        t = time.perf_counter()
        mesh = load_mesh(p)
        acc["load"].append(time.perf_counter() - t)
        t = time.perf_counter()
        walk(correspond(mesh).timings_s)
        acc["correspond (wall)"].append(time.perf_counter() - t)
    print(f"imports + template: {startup:.2f} s; {len(files)} scans")
    print("| stage | median s | min s | max s |\n|---|---|---|---|")
    for k, v in acc.items():
        print(f"| {k} | {statistics.median(v):.3f} | {min(v):.3f} | {max(v):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
