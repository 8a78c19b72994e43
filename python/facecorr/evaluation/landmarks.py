"""``facecorr eval landmarks``: the paper's Tables 1/2 on a synthetic database.

Predicts the 8 landmarks on the evaluation scans (test split, neutral + the six expressions at the
highest level, like the paper's 350 test scans), in a process pool with a progress bar, and writes
``landmarks_table.md``, ``landmarks_table.csv`` and ``landmarks_per_scan.json``: per landmark the
mean ± std and max of the Euclidean error (mm) and the detection rates T10/T20/T30 (% of scans
with an error below 10/20/30 mm). A scan whose prediction failed counts as a miss at every
threshold (its error is infinite) and is listed.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..names import LANDMARK_NAMES

PRETTY = {n: n.replace("_", " ").capitalize() for n in LANDMARK_NAMES}


def _eval_one(job):
    """Worker: predict one scan and measure it; never raises."""
    rec, model_path, rotate_seed, options = job
    from ..io import load_mesh
    from ..geometry.mesh import Mesh
    from ..landmarks.predict import predict_landmarks

    t0 = time.perf_counter()
    try:
        model = _cached_model(model_path)
        mesh = load_mesh(rec["scan"], units="mm")
        gt = json.loads(Path(rec["gt"]).read_text())
        truth = np.array([gt["landmarks"][n] for n in LANDMARK_NAMES], float)
        if rotate_seed is not None:
            from scipy.spatial.transform import Rotation

            r = Rotation.random(random_state=rotate_seed).as_matrix()
            mesh = Mesh(mesh.vertices @ r.T, mesh.faces, source=mesh.source)
            truth = truth @ r.T
        res = predict_landmarks(mesh, model=model, **options)
        pred = res.as_array()
        err = np.linalg.norm(pred - truth, axis=1)
        if rotate_seed is not None:
            pred = pred @ r  # back to the file's frame, for the pictures
        return {"scan": rec["scan"], "gt": rec["gt"], "ok": True, "errors": dict(zip(LANDMARK_NAMES, err.tolist())),
                "predicted": pred.tolist(),
                "confidence": res.confidence, "flags": res.flags, "timings_s": res.timings_s,
                "n_vertices": mesh.n_vertices, "seconds": time.perf_counter() - t0}
    except Exception as e:  # noqa: BLE001 - a failed scan is a result too
        return {"scan": rec["scan"], "ok": False, "error": f"{type(e).__name__}: {e}",
                "seconds": time.perf_counter() - t0}


_MODEL_CACHE = {}

#: Prediction options of the methods ``facecorr eval landmarks --method`` compares.
METHODS = {"default": {}, "paper": {"start_search": "paper", "localise": "bp"}}


def _cached_model(path):
    from ..landmarks.model import load_model

    key = str(path)
    if key not in _MODEL_CACHE:
        _MODEL_CACHE[key] = load_model(path)
    return _MODEL_CACHE[key]


def landmark_table(rows) -> list[dict]:
    """Per landmark: mean, std, max (mm, over successful scans) and T10/T20/T30 (%, over all)."""
    out = []
    for n in LANDMARK_NAMES:
        e = np.array([r["errors"][n] if r["ok"] else np.inf for r in rows], float)
        fin = e[np.isfinite(e)]
        out.append({"landmark": n, "mean": fin.mean() if len(fin) else np.nan, "std": fin.std() if len(fin) else np.nan,
                    "max": fin.max() if len(fin) else np.nan, "T10": 100 * (e < 10).mean(),
                    "T20": 100 * (e < 20).mean(), "T30": 100 * (e < 30).mean(), "n": len(e)})
    return out


def markdown(table, rows) -> str:
    lines = ["| Landmark | Mean ± Std [mm] | Max [mm] | T10 [%] | T20 [%] | T30 [%] |",
             "|---|---|---|---|---|---|"]
    for t in table:
        lines.append(f"| {PRETTY[t['landmark']]} | {t['mean']:.2f} ± {t['std']:.2f} | {t['max']:.2f} | "
                     f"{t['T10']:.2f} | {t['T20']:.2f} | {t['T30']:.2f} |")
    ok = [r for r in rows if r["ok"]]
    all30 = sum(1 for r in ok if max(r["errors"].values()) < 30)
    secs = np.array([r["timings_s"]["total"] for r in ok]) if ok else np.array([np.nan])
    lines += ["", f"Scans: {len(rows)}, failed: {len(rows) - len(ok)}, all 8 within 30 mm: {all30} "
              f"({100 * all30 / max(len(rows), 1):.1f}%). Prediction time per scan: mean {secs.mean():.2f} s, "
              f"max {secs.max():.2f} s."]
    if ok:
        stages = sorted({k for r in ok for k in r["timings_s"] if k != "total"})
        lines.append("Per-stage mean time [s]: " + ", ".join(
            f"{s} {np.mean([r['timings_s'].get(s, 0.0) for r in ok]):.3f}" for s in stages))
    fails = [r for r in rows if not r["ok"]]
    for r in fails[:20]:
        lines.append(f"- failed: {Path(r['scan']).name}: {r['error']}")
    return "\n".join(lines) + "\n"


def evaluate_landmarks(db_dir, out_dir, model=None, workers: int = 2, limit: int | None = None,
                       rotate: bool = False, progress: bool = True, method: str = "default",
                       png: bool = True):
    """Run the evaluation; returns (table rows, per-scan rows) and writes the reports to out_dir.

    ``rotate``: every scan is first turned by a uniformly random rotation of SO(3) (seeded per scan).
    ``method``: a key of :data:`METHODS` ("default", or "paper" for the paper's start + BP).
    ``png``: also write ``landmarks.png`` (:func:`plot_landmarks` of the first 4 and the 4 worst scans).
    """
    from ..threads import process_map

    from ..io.atomic import atomic_path, write_json
    from .registration import select_eval_records
    from ..synth import load_index
    from ..landmarks.model import load_model

    load_model(model)  # validate once, up front: a bad model is the user's error, not 350 failures
    recs = select_eval_records(load_index(db_dir))
    if limit:
        recs = recs[:limit]
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    jobs = [(r, model, (1000 + k) if rotate else None, METHODS[method]) for k, r in enumerate(recs)]
    rows = process_map(_eval_one, jobs, workers=workers, desc="eval landmarks", progress=progress)
    table = landmark_table(rows)
    md = markdown(table, rows)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "landmarks_table.md") as tmp:
        tmp.write_text(md)
    with atomic_path(out / "landmarks_table.csv") as tmp:
        tmp.write_text("landmark,mean_mm,std_mm,max_mm,T10,T20,T30,n\n" + "".join(
            f"{t['landmark']},{t['mean']:.3f},{t['std']:.3f},{t['max']:.3f},{t['T10']:.2f},{t['T20']:.2f},{t['T30']:.2f},{t['n']}\n"
            for t in table))
    write_json(out / "landmarks_per_scan.json", rows)
    ok = [r for r in rows if r["ok"]]
    if png and ok:
        worst = sorted(ok[4:], key=lambda r: -max(r["errors"].values()))[:4]
        plot_landmarks(ok[:4] + worst, out / "landmarks.png")
    return table, rows, md


def plot_landmarks(rows, path, cols: int = 4) -> None:
    """PNG of scans with their true (green) and predicted (red) landmarks, one panel per row of
    ``evaluate_landmarks`` (needs "scan", "gt", "predicted"), each turned to a front view by a
    rigid fit of its true landmarks onto the template's, titled with its largest error (mm)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.atomic import atomic_path
    from ..io import load_mesh
    from ..geometry.transforms import kabsch
    from ..render import draw_mesh
    from ..template import load_template

    tpl = load_template()
    ref = tpl.vertices[tpl.landmark_ids]
    n = len(rows)
    nrow = (n + cols - 1) // cols
    fig, axes = plt.subplots(nrow, cols, figsize=(3.2 * cols, 3.6 * nrow), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax, row in zip(axes.ravel(), rows):
        mesh = load_mesh(row["scan"], units="mm")
        gt = json.loads(Path(row["gt"]).read_text())
        truth = np.array([gt["landmarks"][k] for k in LANDMARK_NAMES], float)
        pred = np.asarray(row["predicted"], float)
        r, t = kabsch(truth, ref)
        v = mesh.vertices @ r.T + t
        keep = np.linalg.norm(v - ref.mean(axis=0), axis=1) < 95.0  # the face, not the whole head
        draw_mesh(ax, v, mesh.faces[keep[mesh.faces].all(axis=1)])
        tp, pp = truth @ r.T + t, pred @ r.T + t
        ax.scatter(tp[:, 0], tp[:, 1], s=22, c="lime", edgecolors="black", linewidths=0.5, zorder=6)
        ax.scatter(pp[:, 0], pp[:, 1], s=30, c="red", marker="x", linewidths=1.2, zorder=7)
        name = Path(row["scan"]).stem.replace("_F3D", "")
        ax.set_title(f"{name}: max {max(row['errors'].values()):.1f} mm", fontsize=9)
        ax.axis("off")
    fig.suptitle("landmarks: true (green dots) and predicted (red crosses)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
