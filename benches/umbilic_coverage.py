"""How many of the 8 landmarks have an umbilic within 5 mm, on synthetic scans (noisy, ~1-2 mm).

Run: .venv/bin/python benches/umbilic_coverage.py DB_DIR [N_SCANS]
(DB_DIR from `facecorr synth DB_DIR --preset tiny`), or `... umbilic_coverage.py --ict` for the
noise-free ICT neutral face. Prints, per parameter setting, the mean number of umbilics and of
covered landmarks, next to the coverage of as many vertices drawn at random (the baseline that
umbilics have to beat to be a useful sampling).
"""

import json
import sys
from pathlib import Path

import numpy as np

from facecorr.geometry import curvature as C
from facecorr.io import load_mesh
from facecorr.names import LANDMARK_NAMES
from facecorr.synth import load_index

SETTINGS = {
    "defaults (2 rings, no smoothing)": (dict(), dict()),
    "2 rings, smooth 2": (dict(), dict(smooth_iters=2)),
    "radius 3 mm": (dict(radius=3.0), dict()),
    "radius 3 mm, smooth 1": (dict(radius=3.0), dict(smooth_iters=1)),
    "radius 3 mm, smooth 2": (dict(radius=3.0), dict(smooth_iters=2)),
    "radius 5 mm, smooth 1": (dict(radius=5.0), dict(smooth_iters=1)),
    "radius 3 mm, smooth 1, ring 1, threshold 1": (dict(radius=3.0), dict(smooth_iters=1, ring=1, threshold=1.0)),
    "2 rings, smooth 1, ring 1, threshold 1": (dict(), dict(smooth_iters=1, ring=1, threshold=1.0)),
}


def main(db, n=10):
    recs = load_index(db)[:n]
    res = {k: ([], [], []) for k in SETTINGS}
    rng = np.random.default_rng(0)
    edge = []
    for r in recs:
        mesh, _ = load_mesh(r["scan"]).largest_component()
        gt = json.loads(Path(r["gt"]).read_text())["landmarks"]
        L = np.array([gt[k] for k in LANDMARK_NAMES])
        e = mesh.edges
        edge.append(np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1).mean())
        for name, (ck, uk) in SETTINGS.items():
            k1, k2, _, _ = C.principal_curvatures(mesh.vertices, mesh.faces, **ck)
            ids = C.umbilics(mesh.vertices, mesh.faces, k1, k2, **uk)
            d = np.linalg.norm(L[:, None] - mesh.vertices[ids][None], axis=2).min(axis=1)
            res[name][0].append(len(ids))
            res[name][1].append((d < 5).sum())
            # baseline: as many vertices drawn at random (uniform over the vertices)
            rand = rng.choice(mesh.n_vertices, size=max(len(ids), 1), replace=False)
            dr = np.linalg.norm(L[:, None] - mesh.vertices[rand][None], axis=2).min(axis=1)
            res[name][2].append((dr < 5).sum())
    print(f"{len(recs)} scans, mean edge {np.mean(edge):.2f} mm, mean {mesh.n_vertices} vertices (last)")
    print("| setting | umbilics | landmarks with an umbilic within 5 mm (of 8) | same number of random vertices |")
    print("|---|---|---|---|")
    for name, (nu, nc, nr) in res.items():
        print(f"| {name} | {np.mean(nu):.0f} | {np.mean(nc):.2f} (min {min(nc)}) | {np.mean(nr):.2f} |")


def main_ict(draws=20):
    from importlib.resources import files

    from facecorr.geometry.mesh import Mesh
    from facecorr.names import LANDMARK_IBUG68

    d = np.load(files("facecorr") / "data/ict/ict_face_model.npz")
    m = Mesh(d["neutral"], d["triangles"])
    face, old = m.submesh(d["part_id"] == 0)
    face, o2 = face.largest_component()
    new = np.full(m.n_vertices, -1)
    new[old[o2]] = np.arange(face.n_vertices)
    L = face.vertices[new[d["landmarks68"][list(LANDMARK_IBUG68)]]]
    rng = np.random.default_rng(0)
    print(f"ICT neutral, part 'face': {face.n_vertices} vertices")
    print("| setting | umbilics | landmarks with an umbilic within 5 mm (of 8) | random (mean of 20 draws) |")
    print("|---|---|---|---|")
    for name, (ck, uk) in SETTINGS.items():
        k1, k2, _, _ = C.principal_curvatures(face.vertices, face.faces, **ck)
        ids = C.umbilics(face.vertices, face.faces, k1, k2, **uk)
        d = np.linalg.norm(L[:, None] - face.vertices[ids][None], axis=2).min(axis=1)
        rand = [(np.linalg.norm(L[:, None] - face.vertices[rng.choice(face.n_vertices, max(len(ids), 1),
                                                                          replace=False)][None],
                                axis=2).min(axis=1) < 5).sum() for _ in range(draws)]
        print(f"| {name} | {len(ids)} | {(d < 5).sum()} | {np.mean(rand):.2f} |")


if __name__ == "__main__":
    if sys.argv[1] == "--ict":
        main_ict()
    else:
        main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 10)
