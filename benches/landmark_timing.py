"""Per-stage timing of facecorr.landmarks.predict_landmarks on real scans, and an output check.

Usage:
  python benches/landmark_timing.py DB MODEL.npz [--n 10] [--method default|paper]
         [--min-vertices 50000] [--save REF.npz] [--ref REF.npz]

``--min-vertices``: scans with fewer vertices are midpoint-subdivided (each triangle into 4, the
surface unchanged) until they reach it, to time the issue's 50k-vertex case. One scan at a time,
FACECORR_THREADS threads (2 by default).

Predicts the landmarks of the first ``--n`` test scans of a synthetic database (every 7th record
from the test split, so several subjects/expressions), prints the median seconds per stage and, with
``--ref``, the max landmark position difference (mm) and chosen-vertex mismatches against a saved
reference run (``--save`` writes one).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("db")
    ap.add_argument("model")
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--method", default="default", choices=["default", "paper"])
    ap.add_argument("--min-vertices", type=int, default=0)
    ap.add_argument("--save")
    ap.add_argument("--ref")
    a = ap.parse_args()

    from facecorr.io import load_mesh
    from facecorr.evaluation.landmarks import METHODS
    from facecorr.landmarks.model import load_model
    from facecorr.landmarks.predict import predict_landmarks
    from facecorr.geometry.mesh import Mesh
    from facecorr.names import LANDMARK_NAMES
    from facecorr.synth import load_index

    recs = load_index(a.db)
    test = [r for r in recs if r.get("split", "test") == "test"] or recs
    recs = test[:: max(1, len(test) // a.n)][: a.n]
    model = load_model(a.model)
    rows, pos, vids, names, nverts = [], [], [], [], []
    for rec in recs:
        mesh = load_mesh(rec["scan"], units="mm")
        while mesh.n_vertices < a.min_vertices:
            import trimesh.remesh

            v, f = trimesh.remesh.subdivide(mesh.vertices, mesh.faces)
            mesh = Mesh(v, f, source=mesh.source)
        t0 = time.perf_counter()
        res = predict_landmarks(mesh, model=model, **METHODS[a.method])
        wall = time.perf_counter() - t0
        t = dict(res.timings_s)
        t["wall"] = wall
        rows.append(t)
        pos.append(res.as_array())
        vids.append([res.vertex_ids[n] for n in LANDMARK_NAMES])
        names.append(rec["scan"])
        nverts.append(mesh.n_vertices)
        print(f"{rec['scan'].split('/')[-1]:40s} N={mesh.n_vertices:6d} total={t['total']:.3f}s", flush=True)
    pos, vids = np.array(pos), np.array(vids)
    stages = list(rows[0])
    print(f"\nmedian over {len(rows)} scans (median N = {int(np.median(nverts))} vertices)")
    print(f"{'stage':12s} {'median s':>9s} {'max s':>8s}")
    for s in stages:
        v = [r.get(s, 0.0) for r in rows]
        print(f"{s:12s} {np.median(v):9.3f} {np.max(v):8.3f}")
    if a.save:
        np.savez(a.save, positions=pos, vertex_ids=vids, scans=np.array(names))
        print(f"saved reference {a.save}")
    if a.ref:
        ref = np.load(a.ref)
        assert list(ref["scans"]) == names, "reference was made on other scans"
        d = np.linalg.norm(pos - ref["positions"], axis=-1)
        print(f"max position difference vs reference: {d.max():.3e} mm; "
              f"vertex mismatches: {int((vids != ref['vertex_ids']).sum())} of {vids.size}")


if __name__ == "__main__":
    main()
