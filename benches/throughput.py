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

    python benches/throughput.py [--folder DIR] [--workers 2] [--repeat 3] [--no-peers]

Without --folder the scans are synthesised once into out/bench_throughput (bu3dfe preset,
3 subjects, the evaluation subset, ``--crop none``, seed 7: 21 scans).
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


def time_batch(db: Path, workers: int) -> dict:
    recs = scans_of(db)
    with tempfile.TemporaryDirectory() as tmp:
        flat = Path(tmp) / "in"
        flat.mkdir()
        for r in recs:
            shutil.copy(db / r["scan"], flat / Path(r["scan"]).name)
        t0 = time.perf_counter()
        subprocess.run(CLI + ["batch", str(flat), str(Path(tmp) / "out"), "--workers", str(workers)],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        n_ok = len([p for p in (Path(tmp) / "out").glob("*.json") if p.name != "failures.json"])
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return {"scans": len(recs), "registered": n_ok, "wall_s": wall, "s_per_scan": wall / len(recs),
            "scans_per_min": 60.0 * len(recs) / wall, "peak_rss_mb": peak_mb}


def time_register(db: Path, repeat: int) -> float:
    scan = db / scans_of(db)[0]["scan"]
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeat):
            t0 = time.perf_counter()
            subprocess.run(CLI + ["register", str(scan), "-o", str(Path(tmp) / f"r{k}.ply")], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", type=Path, default=None, help="a `facecorr synth` folder (default: synthesised)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="runs of the single register command")
    ap.add_argument("--no-peers", action="store_true", help="skip trimesh NICP and MeshMonk")
    a = ap.parse_args(argv)
    db = a.folder or synth_folder(Path("out/bench_throughput"))
    os.environ.setdefault("FACECORR_THREADS", "2")

    b = time_batch(db, a.workers)
    print(f"batch --workers {a.workers}: {b['scans']} scans ({b['registered']} registered) in {b['wall_s']:.1f} s: "
          f"{b['s_per_scan']:.3f} s/scan, {b['scans_per_min']:.1f} scans/min; peak RSS {b['peak_rss_mb']:.0f} MB",
          flush=True)
    single = time_register(db, a.repeat)
    print(f"single `facecorr register`, end to end: {single:.2f} s (median of {a.repeat})", flush=True)
    rows = [("facecorr batch (automatic landmarks)", b["s_per_scan"])]
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
        print(f"| {name} | {s:.3f} | {s / b['s_per_scan']:.1f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
