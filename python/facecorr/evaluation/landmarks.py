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
    rec, model_path, rotate_seed, (options, refine) = job
    from ..io import load_mesh
    from ..geometry.mesh import Mesh
    from ..landmarks.predict import PredictOptions
    from ..pipeline import CorrespondOptions
    from ..pipeline.landmarks import locate_landmarks

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
        res = locate_landmarks(mesh, model=model, refine=refine,
                               options=CorrespondOptions(predict=PredictOptions(**options)))
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

#: The methods ``facecorr eval landmarks --method`` compares: (prediction options, refined by the
#: registration?). "default" is what ``facecorr landmarks`` writes (:func:`facecorr.pipeline.
#: landmarks.locate_landmarks`), "fast" its prediction alone (``--fast``), "paper" the paper's
#: start and BP.
METHODS = {"default": ({}, True), "fast": ({}, False), "paper": ({"start_search": "paper", "localise": "bp"}, False)}


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
                       png: bool = True, on_row=None, split: str = "test"):
    """Run the evaluation; returns (table rows, per-scan rows) and writes the reports to out_dir.

    ``rotate``: every scan is first turned by a uniformly random rotation of SO(3) (seeded per scan).
    ``method``: a key of :data:`METHODS` ("default", or "paper" for the paper's start + BP).
    ``png``: also write ``landmarks.png`` (:func:`plot_landmarks` of the first 4 and the 4 worst scans).
    ``on_row``: called with each per-scan row as it comes (a run log).
    ``split``: the subjects evaluated ("test"; "ood_test" or "ood_holdout" on a ``bu3dfe-ood`` database).
    """
    from ..landmarks.model import load_model
    from ..render import plot_landmarks
    from ..template import load_template
    from .runner import run_on_eval_scans, write_report

    load_model(model)  # validate once, up front: a bad model is the user's error, not 350 failures
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    rows = run_on_eval_scans(db_dir, _eval_one, lambda k, r: (r, model, (1000 + k) if rotate else None, METHODS[method]),
                             workers=workers, limit=limit, split=split, desc="eval landmarks", progress=progress,
                             on_row=on_row)
    table = landmark_table(rows)
    md = markdown(table, rows)
    out = Path(out_dir)
    write_report(out, "landmarks", md, table, "landmark,mean_mm,std_mm,max_mm,T10,T20,T30,n",
                 "{landmark},{mean:.3f},{std:.3f},{max:.3f},{T10:.2f},{T20:.2f},{T30:.2f},{n}", rows)
    ok = [r for r in rows if r["ok"]]
    if png and ok:
        worst = sorted(ok[4:], key=lambda r: -max(r["errors"].values()))[:4]
        tpl = load_template()
        plot_landmarks(ok[:4] + worst, out / "landmarks.png", tpl.vertices[tpl.landmark_ids])
    return table, rows, md
