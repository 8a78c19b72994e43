"""Colour transfer accuracy on synthetic scans with an analytic colour (issue 15 target: mean
absolute difference <= 12/255 between each registered vertex's colour and the scan's colour at
its true corresponding point).

    python benches/colour_transfer.py [--out out/colour_transfer] [--subjects 3] [--limit 0]

Synthesises the evaluation subset (neutral + 6 expressions at level 4) of ``--subjects`` subjects
twice, with ``facecorr synth --colour vertex`` (PLY with per-vertex RGB) and ``--colour texture``
(OBJ + MTL + PNG), same seed (same geometry), and registers every test-split scan fully
automatically (``facecorr.correspond``, predicted landmarks). The scans' colour is
``facecorr.synth.colour.skin_colour`` of the material position, so the true colour of template
vertex ``i`` is ``skin_colour(neutral[template.ict_vertex[i]])`` exactly.

Measured on the vertices that have colour (covered: a scan vertex within 3 mm) and whose true
point is on the scan (the true point, ``pose`` applied to the deformed model's vertex, within
1 mm of the scan surface; not over a hole or beyond the crop):

* ``error``: mean over R, G, B of |registered colour - true colour|, in 1/255 units;
* ``vs scan``: the same against the scan's own colour sampled at the true point (the issue's
  wording; differs from ``error`` by the representation cost below);
* ``floor``: the same for the scan sampled at the true point itself (what the scan's colour
  representation costs: 8-bit vertex colours interpolated linearly, or the texture);
* the colour step's time per scan (``timings_s["colour"]``).

Then times the colour step alone on a denser scan (0.85 mm sampling, ~50k vertices, the issue's
size), 5,325 queries at the template's true points: CPU time (all threads of the process: a
loaded machine inflates the wall time, not this) and wall time, best of 5, with and without
building the scan's closest-point structures first.

Last, the closest-point search against brute force: 2,000 queries within ~1-2 mm of a scan
(surface points moved 0.7 mm per axis, Gaussian), the triangles around the k nearest vertices
(k = 1, 2, 4, 6, 8) against the nearest point of every triangle within 10 mm
(``facecorr.synth.scanner.closest_point_on_mesh``, an independent implementation).

Prints a Markdown table per source and writes ``colour_transfer.json`` (per scan) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np


def make_db(root: Path, colour: str, subjects: int) -> Path:
    from facecorr.synth import generate

    db = root / f"db_{colour}"
    if not (db / "index.json").exists():
        generate(db, preset="tiny", seed=0, workers=1, subjects=subjects, subset="eval", colour=colour)
    return db


def evaluate_scan(rec: dict, seed: int, template) -> dict:
    from facecorr import correspond, load_mesh
    from facecorr.geometry.colour import colours_at
    from facecorr.synth import load_ict, model_vertices
    from facecorr.synth.colour import skin_colour

    mesh = load_mesh(rec["scan"], units="mm")
    res = correspond(mesh, template=template)
    with np.load(rec["dense"]) as d:
        pose = d["pose"]
    V, _ = model_vertices(seed, rec["subject"], rec["expression"], rec["level"])
    ict = np.asarray(template.ict_vertex)
    true_points = V[ict] @ pose[:, :3].T + pose[:, 3]
    true_colour = skin_colour(load_ict().neutral[ict])
    _, _, d_true = mesh.triangle_set.closest(true_points)
    on_scan = d_true <= 1.0
    has_colour = np.isfinite(res.colors).all(axis=1)
    m = has_colour & on_scan
    err = np.abs(res.colors[m] - true_colour[m]).mean(axis=1) * 255.0
    at_true = colours_at(mesh, true_points[m])[0]
    floor = np.abs(at_true - true_colour[m]).mean(axis=1) * 255.0
    vs_scan = np.abs(res.colors[m] - at_true).mean(axis=1) * 255.0
    return {"scan": Path(rec["scan"]).name, "source": res.color_source, "n_vertices": int(len(ict)),
            "n_coloured": int(has_colour.sum()), "n_on_scan": int(on_scan.sum()), "n_measured": int(m.sum()),
            "error_mean": float(err.mean()), "error_median": float(np.median(err)),
            "error_p95": float(np.percentile(err, 95)), "error_max": float(err.max()),
            "floor_mean": float(floor.mean()), "vs_scan_mean": float(vs_scan.mean()), "colour_s": float(res.timings_s.get("colour", np.nan)),
            "errors": err.astype(np.float32).tolist()}


def time_colour_step(out: Path, template) -> str:
    """Colour step timings on a ~50k-vertex scan (module docstring); returns a Markdown line."""
    from facecorr import load_mesh
    from facecorr.geometry.colour import colours_at
    from facecorr.synth import model_vertices
    from facecorr.synth.generate import generate_scan

    rec = generate_scan(out / "dense", subject="M0001", expression="SU", level=4, seed=0, colour="vertex", spacing=0.85)
    with np.load(rec["dense"]) as d:
        pose = d["pose"]
    V, _ = model_vertices(0, "M0001", "SU", 4)
    q = V[np.asarray(template.ict_vertex)] @ pose[:, :3].T + pose[:, 3]
    rows = {}
    for fresh in (True, False):
        cpu, wall = [], []
        mesh = load_mesh(rec["scan"], units="mm")
        for _ in range(5):
            if fresh:
                mesh = load_mesh(rec["scan"], units="mm")
            c0, w0 = time.process_time(), time.perf_counter()
            colours_at(mesh, q)
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
        rows[fresh] = (min(cpu), min(wall))
    n = load_mesh(rec["scan"], units="mm").n_vertices
    return (f"colour step on a {n:,}-vertex scan, {len(q):,} queries (best of 5): "
            f"{1e3 * rows[False][0]:.0f} ms CPU / {1e3 * rows[False][1]:.0f} ms wall; including building the KD-tree and "
            f"triangle set (in `facecorr register` the registration has built the KD-tree "
            f"already): {1e3 * rows[True][0]:.0f} ms CPU / {1e3 * rows[True][1]:.0f} ms wall")


def closest_point_check(out: Path) -> str:
    """The closest-point search against brute force (module docstring); returns a Markdown line."""
    from facecorr import load_mesh
    from facecorr.geometry.closest import TriangleSet
    from facecorr.synth.scanner import closest_point_on_mesh

    scan = sorted((out / "db_vertex").rglob("*.ply"))[0]
    mesh = load_mesh(scan, units="mm")
    rng = np.random.default_rng(0)
    f = rng.integers(0, mesh.n_faces, 2000)
    w = rng.dirichlet([1.0, 1.0, 1.0], 2000)
    q = np.einsum("qk,qkd->qd", w, mesh.vertices[mesh.faces[f]]) + rng.normal(size=(2000, 3)) * 0.7
    ref, _ = closest_point_on_mesh(q, mesh.vertices, mesh.faces, 10.0)
    ts = TriangleSet(mesh.vertices, mesh.faces)
    parts = []
    for k in (1, 2, 4, 6, 8):
        d = ts.closest(q, k=k)[2]
        excess = d - ref
        parts.append(f"k={k}: {int((excess > 1e-9).sum())} farther (max {excess.max():.2g} mm)")
    return f"closest points vs brute force on {scan.name} ({mesh.n_vertices:,} vertices), 2,000 queries: " + "; ".join(parts)


def main(argv=None) -> int:
    from tqdm import tqdm

    from facecorr.synth import load_index
    from facecorr.template import load_template

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/colour_transfer")
    ap.add_argument("--subjects", type=int, default=3, help="subjects synthesised (the test-split ones are measured)")
    ap.add_argument("--limit", type=int, default=0, help="measure only the first N test scans per source")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    template = load_template()
    rows = []
    for colour in ("vertex", "texture"):
        db = make_db(out, colour, args.subjects)
        seed = json.loads((db / "index.json").read_text())["seed"]
        recs = [r for r in load_index(db) if r["split"] == "test"]
        if args.limit:
            recs = recs[:args.limit]
        for rec in tqdm(recs, desc=f"colour {colour}", unit="scan"):
            rows.append(evaluate_scan(rec, seed, template))
    lines = ["| source | scans | vertices measured (of 5325) | mean error [1/255] | median | p95 | worst scan mean "
             "| vs scan at the true point | floor (scan at the true point vs truth) | colour step [s, median] |",
             "|---|" + "---|" * 9]
    for colour in ("vertex", "texture"):
        rs = [r for r in rows if r["source"] == colour]
        if not rs:
            continue
        pooled = np.concatenate([np.asarray(r["errors"]) for r in rs])
        lines.append(
            f"| {colour} | {len(rs)} | {statistics.mean(r['n_measured'] for r in rs):.0f} | {pooled.mean():.2f} | "
            f"{np.median(pooled):.2f} | {np.percentile(pooled, 95):.2f} | {max(r['error_mean'] for r in rs):.2f} | "
            f"{np.mean([r['vs_scan_mean'] for r in rs]):.2f} | {np.mean([r['floor_mean'] for r in rs]):.2f} | "
            f"{statistics.median(r['colour_s'] for r in rs):.3f} |")
    table = "\n".join(lines) + "\n\n" + time_colour_step(out, template) + "\n\n" + closest_point_check(out)
    print(table)
    for r in rows:
        r.pop("errors")
    (out / "colour_transfer.json").write_text(json.dumps(rows, indent=1) + "\n")
    (out / "colour_transfer.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
