"""`facecorr model build` locally and on a Dask LocalCluster: time and agreement (issue 16).

    python benches/model_cluster.py RESULTS [--workers 2] [--neutral] [--runs 2]

Runs `facecorr model build RESULTS -o ...` and the same with `--scheduler local --workers N` as
fresh processes, alternating (local, dask, dask, local for --runs 2), each timed from start to
exit (wall, and the CPU of the command and its children: the cluster's worker processes), then
compares every model with the first local one: the largest differences of the mean, components,
variances and scores, relative to their largest value.
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def run(cmd):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode:
        sys.exit(f"{' '.join(cmd)} failed:\n{r.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, r.stdout.strip().splitlines()[-1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("results")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--neutral", action="store_true")
    ap.add_argument("--runs", type=int, default=2)
    a = ap.parse_args()
    from facecorr.model import ShapeModel

    base = [sys.executable, "-m", "facecorr.cli", "model", "build", a.results]
    extra = ["--neutral"] if a.neutral else []
    order = []
    for i in range(a.runs):
        order += [("local", []), ("dask", ["--scheduler", "local", "--workers", str(a.workers)])]
        if i % 2:
            order[-2:] = order[-2:][::-1]
    print(f"{a.results}: {' '.join(extra) or 'registered shapes'}, --workers {a.workers}, "
          f"load average {os.getloadavg()[0]:.1f} at the start")
    times = {"local": [], "dask": []}
    with tempfile.TemporaryDirectory() as tmp:
        models = []
        for k, (what, opts) in enumerate(order):
            out = Path(tmp) / f"{k}_{what}.npz"
            wall, cpu, line = run(base + ["-o", str(out)] + extra + opts)
            times[what].append(wall)
            print(f"  run {k + 1} {what:5s}: {wall:6.2f} s wall, {cpu:6.2f} s CPU   {line.split(': ', 1)[1][:60]}")
            models.append((what, ShapeModel.load(out)))
        ref = models[0][1]
        for k, (what, m) in enumerate(models[1:], start=2):
            assert m.names == ref.names and m.n_modes == ref.n_modes
            diffs = {f: float(np.abs(getattr(m, f) - getattr(ref, f)).max() / np.abs(getattr(ref, f)).max())
                     for f in ("mean", "components", "variances", "scores")}
            print(f"  run {k} {what} vs run 1 local, max |difference| / max |value|: "
                  + ", ".join(f"{f} {v:.1e}" for f, v in diffs.items()))
    lo, da = np.mean(times["local"]), np.mean(times["dask"])
    print(f"mean wall: local {lo:.2f} s, Dask LocalCluster {da:.2f} s (ratio {da / lo:.2f})")
    # the build alone, in this process, on a cluster started beforehand (no start-up, no imports)
    import distributed

    from facecorr.model import build_model
    from facecorr.model.distributed import build_model_on_cluster

    with distributed.LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                  scheduler_kwargs={"dashboard_address": ":0"}, silence_logs=40) as c, \
            distributed.Client(c) as client:
        t0 = time.perf_counter()
        build_model(a.results, neutral=a.neutral, progress=False)
        t1 = time.perf_counter()
        build_model_on_cluster(a.results, client, neutral=a.neutral, progress=False)
        t2 = time.perf_counter()
        build_model_on_cluster(a.results, client, neutral=a.neutral, progress=False)
        t3 = time.perf_counter()
    print(f"in one process, cluster already running: build_model {t1 - t0:.2f} s, build_model_on_cluster "
          f"{t2 - t1:.2f} s then {t3 - t2:.2f} s")


if __name__ == "__main__":
    main()
