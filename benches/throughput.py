"""Throughput (issue 17): scans per minute of ``facecorr batch --workers 2`` beside the peers.

In one run, on one fixed folder of raw (uncropped, ~56k-vertex) synthetic scans:

1. ``facecorr batch IN OUT --workers W`` as a user runs it (a fresh process, imports included):
   wall seconds per scan, scans per minute, and the peak resident memory of the largest process
   (``getrusage(RUSAGE_CHILDREN).ru_maxrss``: the batch's workers are waited for by it, so their
   peak counts);
2. ``facecorr register SCAN -o OUT.ply`` end to end (median of ``--repeat`` runs);
3. the peers on one scan each, both given the true 8 landmarks (the template moved onto the scan
   by the same landmark similarity facecorr starts from): trimesh's
   ``registration.nricp_amberg`` (default schedule, KD-tree closest points) and MeshMonk's
   ``nonrigid_register`` with Cliniface's settings (σ 1.6, 80 iterations, κ 10, flag threshold
   0.9, push-pull equalisation on). Peers run single-process, as they come.

Prints a Markdown table with the ratios (peer seconds per scan / facecorr batch seconds per scan).
Besides wall times it reports CPU seconds (user + sys of the command and its workers) and the
peak RSS of the largest process, per command: on a shared machine wall times are noisy, CPU times
much less so.

``--baseline DIR`` also runs the facecorr commands of another checkout (DIR = its ``python/``
folder with its built extension, put first on PYTHONPATH), alternating before / after runs
(``--rounds`` of each), and prints both with the ratios: before and after side by side in one run.

    python benches/throughput.py [--folder DIR] [--workers 2] [--repeat 3] [--no-peers] [--baseline DIR --rounds 2]

Each facecorr checkout measured has its bytecode compiled first (``compileall``), as ``pip
install`` does for a wheel: with ``PYTHONDONTWRITEBYTECODE`` set (as on our CI machines) every
command would otherwise compile the package's sources again (~70 ms a command).

Without --folder the scans are synthesised once into out/bench_throughput (bu3dfe preset,
3 subjects, the evaluation subset, ``--crop none``, seed 7: 21 scans).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLI = [sys.executable, "-m", "facecorr.cli"]


def synth_folder(path: Path) -> Path:
    """The fixed folder: 21 raw scans (and their ground truth) of the bu3dfe preset."""
    if not (path / "index.json").exists():
        print(f"synthesising the scans into {path} ...", flush=True)
        subprocess.run(CLI + ["synth", str(path), "--preset", "bu3dfe", "--subjects", "3", "--subset", "eval",
                              "--crop", "none", "--seed", "7", "--workers", "2", "--quiet"], check=True)
    return path


def scans_of(db: Path) -> list[dict]:
    return json.loads((db / "index.json").read_text())["scans"]


#: Runs a command and prints its (and its descendants') CPU seconds and peak RSS: the resource
#: use of one command, whatever ran before in this process.
_MEASURE = ("import resource, subprocess, sys; rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, "
            "stderr=subprocess.DEVNULL).returncode; u = resource.getrusage(resource.RUSAGE_CHILDREN); "
            "print(u.ru_utime + u.ru_stime, u.ru_maxrss / 1024.0, rc)")


def run_measured(args: list, pythonpath: str | None = None, why=lambda: "") -> dict:
    """Run ``CLI + args``: wall s, CPU s (user + sys, workers included), peak RSS MB of the largest
    process. On a non-zero exit it raises, with ``why()`` (e.g. the batch's failures.json) appended."""
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _MEASURE, *CLI, *args], env=env, check=True, capture_output=True,
                         text=True).stdout.split()
    wall = time.perf_counter() - t0
    if int(out[2]) != 0:
        raise RuntimeError(f"facecorr {args[0]} exited with {out[2]}{why()}")
    return {"wall_s": wall, "cpu_s": float(out[0]), "peak_rss_mb": float(out[1])}


def compile_bytecode(pythonpath: str | None = None) -> None:
    """Write the ``__pycache__`` of the facecorr package that ``pythonpath`` (or this environment)
    imports, as ``pip install`` does for a wheel."""
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    subprocess.run([sys.executable, "-c", "import compileall, os, facecorr; "
                    "compileall.compile_dir(os.path.dirname(facecorr.__file__), quiet=1)"], env=env, check=True)


def time_batch(db: Path, workers: int, pythonpath: str | None = None) -> dict:
    recs = scans_of(db)
    with tempfile.TemporaryDirectory() as tmp:
        flat = Path(tmp) / "in"
        flat.mkdir()
        for r in recs:
            shutil.copy(db / r["scan"], flat / Path(r["scan"]).name)
        failures = Path(tmp) / "out" / "failures.json"
        m = run_measured(["batch", str(flat), str(Path(tmp) / "out"), "--workers", str(workers)], pythonpath,
                         why=lambda: f": {failures.read_text()}" if failures.exists() else "")
        n_ok = len([p for p in (Path(tmp) / "out").glob("*.json") if p.name != "failures.json"])
    n = len(recs)
    return {"scans": n, "registered": n_ok, **m, "s_per_scan": m["wall_s"] / n, "cpu_s_per_scan": m["cpu_s"] / n,
            "scans_per_min": 60.0 * n / m["wall_s"]}


def time_register(db: Path, repeat: int, pythonpath: str | None = None) -> dict:
    """Medians over ``repeat`` runs of one ``facecorr register`` (wall, CPU, peak RSS)."""
    scan = db / scans_of(db)[0]["scan"]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeat):
            runs.append(run_measured(["register", str(scan), "-o", str(Path(tmp) / f"r{k}.ply")], pythonpath))
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def _aligned_template(db: Path):
    """(template, scan mesh, true landmarks (8, 3), template vertices moved by the landmark similarity)."""
    from facecorr.evaluation import metrics
    from facecorr.io import load_mesh
    from facecorr.names import LANDMARK_NAMES
    from facecorr.registration.alignment import align_landmarks, apply_transform
    from facecorr.template import load_template

    rec = scans_of(db)[0]
    template = load_template()
    mesh = load_mesh(db / rec["scan"], units="mm")
    gt = metrics.load_ground_truth(db / rec["gt"])
    lms = np.array([gt["landmarks"][k] for k in LANDMARK_NAMES])
    ids = np.asarray(template.landmark_ids)
    transform = align_landmarks(np.asarray(template.vertices)[ids], lms, mode="similarity")
    return template, mesh, lms, apply_transform(transform, template.vertices)


def time_nricp(db: Path) -> float:
    import trimesh
    from trimesh.registration import nricp_amberg

    template, mesh, lms, start = _aligned_template(db)
    src = trimesh.Trimesh(start, template.faces, process=False)
    tgt = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    t0 = time.perf_counter()
    nricp_amberg(src, tgt, source_landmarks=np.asarray(template.landmark_ids), target_positions=lms, use_faces=False)
    return time.perf_counter() - t0


def time_meshmonk(db: Path) -> float:
    import meshmonk

    template, mesh, _, start = _aligned_template(db)
    t0 = time.perf_counter()
    meshmonk.nonrigid_register(
        floating_features=meshmonk.features_from_vertices(start.astype(np.float32), np.asarray(template.faces)),
        target_features=meshmonk.features_from_vertices(mesh.vertices.astype(np.float32), mesh.faces),
        floating_faces=np.asarray(template.faces, dtype=np.int32), target_faces=mesh.faces.astype(np.int32),
        num_iterations=80, transform_sigma=1.6, inlier_kappa=10.0, correspondences_flag_threshold=0.9,
        correspondences_equalize_push_pull=True)
    return time.perf_counter() - t0


def _batch_line(label: str, b: dict, workers: int) -> str:
    return (f"{label}batch --workers {workers}: {b['scans']} scans ({b['registered']} registered) in {b['wall_s']:.1f} s: "
            f"{b['s_per_scan']:.3f} s/scan, {b['scans_per_min']:.1f} scans/min; CPU {b['cpu_s_per_scan']:.3f} s/scan; "
            f"peak RSS {b['peak_rss_mb']:.0f} MB")


def _register_line(label: str, r: dict, repeat: int) -> str:
    return (f"{label}single `facecorr register`, end to end: {r['wall_s']:.2f} s wall, {r['cpu_s']:.2f} s CPU, "
            f"peak RSS {r['peak_rss_mb']:.0f} MB (medians of {repeat})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", type=Path, default=None, help="a `facecorr synth` folder (default: synthesised)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="runs of the single register command")
    ap.add_argument("--no-peers", action="store_true", help="skip trimesh NICP and MeshMonk")
    ap.add_argument("--baseline", metavar="DIR", help="another checkout's python/ folder (built): before / after runs")
    ap.add_argument("--rounds", type=int, default=2, help="with --baseline: alternating runs of each")
    a = ap.parse_args(argv)
    db = a.folder or synth_folder(Path("out/bench_throughput"))
    for pp in ([a.baseline] if a.baseline else []) + [None]:
        compile_bytecode(pp)

    if a.baseline:
        res = {"before": [], "after": []}
        for k in range(a.rounds):
            for label, pp in (("before", a.baseline), ("after", None)):
                b = time_batch(db, a.workers, pp)
                r = time_register(db, a.repeat, pp)
                res[label].append((b, r))
                print(_batch_line(f"[{label} {k + 1}] ", b, a.workers), flush=True)
                print(_register_line(f"[{label} {k + 1}] ", r, a.repeat), flush=True)
        med = {lab: {"batch s/scan": statistics.median(b["s_per_scan"] for b, _ in v),
                     "batch CPU s/scan": statistics.median(b["cpu_s_per_scan"] for b, _ in v),
                     "batch peak RSS MB": max(b["peak_rss_mb"] for b, _ in v),
                     "register wall s": statistics.median(r["wall_s"] for _, r in v),
                     "register CPU s": statistics.median(r["cpu_s"] for _, r in v),
                     "register peak RSS MB": max(r["peak_rss_mb"] for _, r in v)} for lab, v in res.items()}
        print(f"\n| measure (medians of {a.rounds} rounds; peaks: max) | before | after | before / after |\n|---|---|---|---|")
        for k in med["before"]:
            x, y = med["before"][k], med["after"][k]
            print(f"| {k} | {x:.3f} | {y:.3f} | {x / y:.2f}x |")
        b_after = min((b for b, _ in res["after"]), key=lambda b: b["s_per_scan"])
    else:
        b_after = time_batch(db, a.workers)
        print(_batch_line("", b_after, a.workers), flush=True)
        print(_register_line("", time_register(db, a.repeat), a.repeat), flush=True)
    rows = [("facecorr batch (automatic landmarks)", b_after["s_per_scan"])]
    if not a.no_peers:
        for name, fn in (("trimesh nricp_amberg (true landmarks)", time_nricp),
                         ("MeshMonk nonrigid_register, Cliniface settings (true landmarks)", time_meshmonk)):
            try:
                s = fn(db)
            except ImportError as e:
                print(f"{name}: not installed ({e})")
                continue
            rows.append((name, s))
            print(f"{name}: {s:.2f} s", flush=True)
    print("\n| method | seconds per scan | ratio to facecorr batch |\n|---|---|---|")
    for name, s in rows:
        print(f"| {name} | {s:.3f} | {s / b_after['s_per_scan']:.1f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
