"""Make a large results folder for timing `facecorr model build`: perturbed copies of real results.

Each result under SRC (``facecorr batch`` output) is copied COPIES times into DST as a new result:
its registered vertices (mm) get a smooth random deformation (three low-frequency sine fields,
about AMPLITUDE mm each), a random rotation and translation, and are written in a random unit
(mm, cm or m) with the JSON's ``units`` (and its points) to match. The copies are *not*
registrations of new scans: they stand in for them when only the reading, alignment and PCA are
timed (issue 15, BENCHMARKS.md).

    python benches/model_results.py SRC DST [--copies 5] [--amplitude 1.0] [--seed 0]
"""

import argparse
import json
from pathlib import Path

import numpy as np

from facecorr.io import UNIT_TO_MM, save_mesh
from facecorr.model.results import find_results, read_results


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", help="a `facecorr batch` output folder")
    ap.add_argument("dst", help="folder to write the copies into (created)")
    ap.add_argument("--copies", type=int, default=5)
    ap.add_argument("--amplitude", type=float, default=1.0, help="mm, per sine field")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    src, dst = Path(a.src), Path(a.dst)
    rs = read_results(src, include_flagged=True, progress=False)
    data = {p.relative_to(src).with_suffix("").as_posix(): d for p, d in find_results(src)}
    n = 0
    for name, v in zip(rs.names, rs.shapes):
        c = v - v.mean(0)
        for k in range(a.copies):
            field = np.zeros_like(v)
            for _ in range(3):
                direction, wave = rng.normal(size=3), rng.normal(size=3) / 40.0
                field += a.amplitude * np.sin(c @ wave + rng.uniform(0, 2 * np.pi))[:, None] * direction / np.linalg.norm(direction)
            r, t = random_rotation(rng), rng.normal(size=3) * 200.0
            units = ["mm", "cm", "m"][rng.integers(3)]
            s = 1.0 / UNIT_TO_MM[units]
            src_s = 1.0 / UNIT_TO_MM[data[name].get("units", "mm")]

            def move(p):  # a point of the source JSON (its units) -> the copy's frame and units
                return None if p is None else (((np.asarray(p) / src_s) @ r.T + t) * s).tolist()

            out = dst / f"{name}_copy{k}"
            out.parent.mkdir(parents=True, exist_ok=True)
            save_mesh(out.with_suffix(".ply"), ((v + field) @ r.T + t, rs.faces), units=units)
            d = dict(data[name], units=units)
            for key in ("landmarks", "landmarks_registered"):
                d[key] = {m: move(p) for m, p in d[key].items()}
            d["ibug68"] = [move(p) for p in (d.get("ibug68") or [])] or None
            d["mhd"] = float(d["mhd"]) / src_s * s
            out.with_suffix(".json").write_text(json.dumps(d))
            n += 1
    print(f"{dst}: {n} results ({a.copies} perturbed copies of each of {len(rs.names)})")


if __name__ == "__main__":
    main()
