"""Throughput of `facecorr batch --scheduler local` (a LocalCluster) against `facecorr batch` (the
local process pool), side by side on the same folder, with identical results required; and the
measurements behind an estimate for a large cluster.

    .venv/bin/python benches/dask_throughput.py [--db /work/db/bu3dfe_eval] [--scans 20] [--workers 2]

Copies the first ``--scans`` scans of the database into a temporary folder, then runs both
commands in the order local, Dask, Dask, local (a drifting load on a shared machine then weighs on
both alike), each as a fresh process timed from start to exit (start-up included). Every run uses
FACECORR_THREADS=``--threads`` (1 by default: facecorr is bitwise reproducible with one thread per
process, so the results must be byte-identical; with more threads the last bits vary from run to
run in either batch). Prints scans/min of each run, the ratio Dask/local of the totals, and checks
that every run wrote the first run's files (meshes byte-equal, JSONs equal but for the timings).

For the estimate it also prints the bytes that travel per scan (the scan read, the results sent
back), the median seconds of one scan on one worker (from the run logs) and the scheduler's own
rate on trivial tasks through the same windowed submit / as_completed loop.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _copy_scans(db: Path, dst: Path, n: int) -> list[Path]:
    scans = sorted(db.rglob("*.ply"))
    scans = [s for s in scans if not s.name.endswith("_dense.ply")][:n]
    if len(scans) < n:
        sys.exit(f"{db}: only {len(scans)} scans")
    for s in scans:
        out = dst / s.relative_to(db)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(s, out)
    return scans


def _run(kind: str, src: Path, out: Path, log: Path, workers: int, threads: str) -> dict:
    cmd = [sys.executable, "-m", "facecorr.cli", "batch", str(src), str(out), "--workers", str(workers),
           "--quiet", "--log", str(log)]
    if kind == "dask":
        cmd += ["--scheduler", "local"]
    env = {**os.environ, "FACECORR_THREADS": threads}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        sys.exit(f"{kind} batch failed ({r.returncode}): {r.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"kind": kind, "wall": wall, "cpu": cpu, "out": out, "log": log}


def _same(a: Path, b: Path) -> tuple[int, list]:
    """(files compared, differences) between two batch outputs."""
    diffs, n = [], 0
    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    if names != sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file()):
        return 0, ["different file lists"]
    for name in names:
        x, y = (a / name).read_bytes(), (b / name).read_bytes()
        n += 1
        if name.endswith(".json"):
            jx, jy = json.loads(x), json.loads(y)
            jx.pop("timings_s", None), jy.pop("timings_s", None)
            if jx != jy:
                diffs.append(name)
        elif x != y:
            diffs.append(name)
    return n, diffs


def _noop(i):
    return i


def _scheduler_rate(workers: int, window: int | None = None, n: int = 3000) -> float:
    """Trivial tasks per second through a LocalCluster with the batch's windowed loop (``window``
    tasks in flight: the batch's own choice for this cluster if None)."""
    from distributed import as_completed

    from facecorr.pipeline.cluster import _window, connect

    with connect("local", workers=workers) as client:
        client.submit(_noop, -1).result()
        t0 = time.perf_counter()
        done, inflight, k = as_completed(loop=client.loop, with_results=True, raise_errors=False), 0, 0
        fixed = window
        window, window_at = fixed or _window(client), time.monotonic()
        while k < n or inflight:
            if time.monotonic() - window_at > 2.0:
                window, window_at = fixed or _window(client), time.monotonic()
            while k < n and inflight < window:
                done.add(client.submit(_noop, k, pure=False))
                k += 1
                inflight += 1
            f, _ = next(done)
            f.release()
            inflight -= 1
        return n / (time.perf_counter() - t0)


def _idle_cpu(workers: int, batch_settings: bool, seconds: float = 20.0) -> tuple:
    """CPU seconds (client process, each worker) an idle LocalCluster burns in ``seconds``: the
    batch's own (``connect("local")``) or one with Dask's default settings."""
    import psutil

    from facecorr.pipeline.cluster import check_workers, connect

    def cpu(p):
        t = p.cpu_times()
        return t.user + t.system

    if batch_settings:
        ctx = connect("local", workers=workers)
    else:
        from contextlib import contextmanager

        import distributed

        @contextmanager
        def ctx_fn():
            with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None,
                                          silence_logs=40) as c, distributed.Client(c) as client:
                yield client
        ctx = ctx_fn()
    with ctx as client:
        check_workers(client, None)
        procs = [psutil.Process()] + [psutil.Process(p) for p in client.run(os.getpid).values()]
        a = [cpu(p) for p in procs]
        time.sleep(seconds)
        b = [cpu(p) for p in procs]
    return tuple(round(y - x, 2) for x, y in zip(a, b))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--db", default="/work/db/bu3dfe_eval")
    ap.add_argument("--scans", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--threads", default="1", help="FACECORR_THREADS of every run (default 1)")
    ap.add_argument("--idle", action="store_true",
                    help="only measure the CPU an idle LocalCluster burns in 20 s (Dask's defaults, the batch's settings)")
    args = ap.parse_args()
    if args.idle:
        for batch in (False, True):
            c, *w = _idle_cpu(args.workers, batch)
            print(f"idle LocalCluster, {'the batch' if batch else 'Dask'}'s settings: 20 s cost {c} s CPU in the client "
                  f"process (scheduler, nannies), {w} s in the workers")
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="facecorr-dask-bench-"))
    try:
        src = tmp / "in"
        scans = _copy_scans(Path(args.db), src, args.scans)
        print(f"{len(scans)} scans from {args.db}, --workers {args.workers}, FACECORR_THREADS={args.threads}, "
              f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
        runs = []
        for i, kind in enumerate(("local", "dask", "dask", "local")):
            r = _run(kind, src, tmp / f"out{i}_{kind}", tmp / f"log{i}_{kind}.jsonl", args.workers, args.threads)
            runs.append(r)
            print(f"  run {i + 1} {kind:5s}: {r['wall']:6.1f} s wall, {r['cpu']:6.1f} s CPU, "
                  f"{60 * len(scans) / r['wall']:5.1f} scans/min")
        for r in runs[1:]:
            n, diffs = _same(runs[0]["out"], r["out"])
            print(f"  {r['out'].name} vs {runs[0]['out'].name}: {n} files, "
                  + ("identical" if not diffs else f"{len(diffs)} differ: {diffs[:3]}"))
        total = {k: sum(r["wall"] for r in runs if r["kind"] == k) for k in ("local", "dask")}
        rate = {k: 60 * 2 * len(scans) / total[k] for k in total}
        print(f"local batch: {rate['local']:.1f} scans/min; Dask LocalCluster: {rate['dask']:.1f} scans/min; "
              f"ratio Dask/local {rate['dask'] / rate['local']:.3f}")
        # the estimate's inputs
        scan_b = statistics.mean((src / s.relative_to(args.db)).stat().st_size for s in scans)
        out = runs[1]["out"]
        res_b = statistics.mean((p.stat().st_size + p.with_suffix(".json").stat().st_size) for p in out.rglob("*.ply"))
        secs = [json.loads(line)["seconds"] for line in runs[1]["log"].read_text().splitlines()]
        print(f"per scan: {scan_b / 1e6:.2f} MB read, {res_b / 1e6:.3f} MB of results sent back; "
              f"median {statistics.median(secs):.2f} s on one worker (Dask run 1 log)")
        print(f"scheduler: {_scheduler_rate(args.workers):.0f} trivial tasks/s through the batch's loop "
              f"(LocalCluster, {args.workers} workers, the batch's window); {_scheduler_rate(args.workers, 200):.0f} "
              f"with 200 in flight (the window of 100 one-thread workers)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
