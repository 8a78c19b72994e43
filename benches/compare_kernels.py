"""Side-by-side timings of facecorr's Rust kernels against the usual Python tools, one table.

    python benches/compare_kernels.py [--repeats N]

- KD-tree: build + 10k queries into 50k random points (k = 1 and 8) vs scipy cKDTree(workers=2);
  the results are checked to be the same (indices equal where distances are not tied).
- Geodesics from one source on a ~45k-vertex face mesh: our FMM vs pygeodesic's exact method
  (reference for the error) and potpourri3d's heat method; seconds and mean relative error.
- Finger Print: 1,000 centres x 8 radii (3.125 ... 25 mm) on the same mesh.

The face mesh: the ICT neutral head's "face" and "head_neck" parts (triangles with all three
vertices in them), subdivided once with trimesh.remesh.subdivide (44,786 vertices, 89,152
triangles, mean edge 2.0 mm). Timings are medians over repeats (wall clock, facecorr with its
default 2 threads); the machine may be shared, so the CPU load is printed too.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from facecorr.geometry.geodesic import GeodesicSolver
from facecorr.geometry.spatial import KDTree

ICT = Path(__file__).resolve().parents[1] / "python" / "facecorr" / "data" / "ict" / "ict_face_model.npz"


def face_mesh():
    z = np.load(ICT)
    V = z["neutral"].astype(np.float64)
    F = z["triangles"].astype(np.int64)
    names = list(z["part_names"])
    keep = np.isin(z["part_id"], [names.index("face"), names.index("head_neck")])
    F = F[keep[F].all(axis=1)]
    m = trimesh.Trimesh(V, F, process=False)
    m.remove_unreferenced_vertices()
    V2, F2 = trimesh.remesh.subdivide(m.vertices, m.faces)
    return np.ascontiguousarray(V2, dtype=np.float64), np.ascontiguousarray(F2, dtype=np.int64)


_CPU = {}


def timed(fn, repeats, key=None):
    """(median wall seconds, last result); the median process CPU seconds go to _CPU[key]."""
    ts, cs, out = [], [], None
    for _ in range(repeats):
        c = time.process_time()
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    if key:
        _CPU[key] = statistics.median(cs)
    return statistics.median(ts), out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    R = args.repeats
    rows = []
    load0 = os.getloadavg()[0]

    # ---- KD-tree ----
    rng = np.random.default_rng(0)
    P = rng.uniform([0, 0, 0], [200, 200, 100], size=(50_000, 3))
    Q = rng.uniform([0, 0, 0], [200, 200, 100], size=(10_000, 3))
    for k in (1, 8):
        t_ours, (d, i) = timed(lambda: KDTree(P).query(Q, k=k), R)
        t_ref, (dr, ir) = timed(lambda: cKDTree(P).query(Q, k=k, workers=2), R)
        same = np.allclose(d, dr, rtol=0, atol=1e-12) and bool(((i == ir) | np.isclose(d, dr, atol=1e-12)).all())
        ratio = t_ref / t_ours
        rows.append((f"KD-tree build + 10k queries into 50k pts, k={k}", f"{t_ours*1e3:.1f} ms",
                     f"cKDTree(workers=2) {t_ref*1e3:.1f} ms", f"{ratio:.2f}x faster",
                     "same results" if same else "RESULTS DIFFER", ">= 1.5x", "met" if ratio >= 1.5 and same else "MISSED"))

    # ---- geodesics on the face mesh ----
    V, F = face_mesh()
    src = int(np.argmax(V[:, 2]))
    import pygeodesic.geodesic as pg
    import potpourri3d as pp3d

    def exact():
        alg = pg.PyGeodesicAlgorithmExact(V, F.astype(np.int32))
        return np.asarray(alg.geodesicDistances(np.array([src], dtype=np.int32), None)[0], dtype=np.float64)

    t_exact, e = timed(exact, max(1, min(R, 3)))
    m = np.isfinite(e) & (e > 0) & (e < 1e30)

    def relerr(d):
        return float(np.mean(np.abs(d[m] - e[m]) / e[m]))

    t_build, solver = timed(lambda: GeodesicSolver(V, F), R)
    t_fmm, d_fmm = timed(lambda: solver.distances(src), R)
    t_fmm_total = t_build + t_fmm
    t_dij, d_dij = timed(lambda: solver.distances(src, method="dijkstra"), R)

    def heat():
        return pp3d.MeshHeatMethodDistanceSolver(V, F).compute_distance(src)

    t_heat, d_heat = timed(heat, max(1, min(R, 3)))
    err_fmm = relerr(d_fmm)
    ratio = t_exact / t_fmm_total
    mesh = f"{len(V)}-vertex face mesh"
    rows.append((f"FMM one source, {mesh} (solver build + query)", f"{t_fmm_total*1e3:.1f} ms "
                 f"(build {t_build*1e3:.1f} + query {t_fmm*1e3:.1f})",
                 f"pygeodesic exact {t_exact:.2f} s", f"{ratio:.0f}x faster",
                 f"mean rel err {err_fmm*100:.3f}%", ">= 5x, <= 1%",
                 "met" if ratio >= 5 and err_fmm <= 0.01 else "MISSED"))
    rows.append((f"Heat method one source, {mesh}", "", f"potpourri3d {t_heat*1e3:.1f} ms (with factorisation)",
                 f"FMM {t_heat/t_fmm_total:.1f}x faster", f"heat mean rel err {relerr(d_heat)*100:.3f}%", "", ""))
    rows.append((f"Dijkstra one source, {mesh} (query)", f"{t_dij*1e3:.1f} ms", "", "",
                 f"mean rel err {relerr(d_dij)*100:.3f}%", "", ""))

    # ---- Finger Print ----
    centers = np.random.default_rng(1).choice(len(V), 1000, replace=False)
    radii = np.linspace(25 / 8, 25, 8)
    t_fp, fp = timed(lambda: solver.fingerprint(centers, radii), R, key="fp")
    cpu = _CPU["fp"]
    rows.append((f"FP 1,000 centres x 8 radii (<= 25 mm), {mesh}",
                 f"{t_fp*1e3:.0f} ms wall (solver built); {cpu*1e3:.0f} ms CPU over both threads",
                 "", "", f"FP mean {fp.mean():.3f}", "<= 0.2 s on 2 cores",
                 "met" if t_fp <= 0.2 else f"MISSED (wall; CPU/2 = {cpu/2*1e3:.0f} ms)"))

    load1 = os.getloadavg()[0]
    hdr = ("kernel", "facecorr (Rust)", "reference", "ratio", "check / accuracy", "target", "status")
    print(f"<!-- 1-min load average {load0:.1f} before, {load1:.1f} after; {os.cpu_count()} CPUs; "
          f"FACECORR_THREADS={os.environ.get('FACECORR_THREADS', '2 (default)')}; repeats {R} (exact/heat {max(1, min(R, 3))}) -->")
    print("| " + " | ".join(hdr) + " |")
    print("|" + "---|" * len(hdr))
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
