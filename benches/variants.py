"""Registration variants side by side on the same scans, in one run (issue 14: measure each idea).

Each variant is a name and a set of option overrides of :class:`facecorr.pipeline.CorrespondOptions`
by dotted path (``register.expression.alpha_prior=2``, ``register.identity=None``,
``predict.eye_patch_radius=20``); values are Python literals. Every variant registers the same
scans (the evaluation subset of a split of a synthetic database), guided by the true landmarks
(``--landmarks gt``) or fully automatically (``predicted``), and the table gives per region the mean
error at the iBUG-68 points, the dense error and the mean over scans, plus per-variant ratios to
the first variant scan by scan (median of the per-scan ratios).

    python benches/variants.py DB --split ood_test --landmarks gt --n 30 \\
        --variant base: --variant nobrow:register.expression.alpha_prior=3 [--artefacts none] [--workers 2]

``--artefacts none`` keeps the scans without artefacts (a ``bu3dfe-ood`` database), ``--artefacts
glasses,hair`` those showing any of the kinds; ``--every K`` takes every K-th scan.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
import time
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import numpy as np

REGIONS = ("brows", "eyes", "nose", "mouth")
#: The iBUG-68 regions (facecorr.evaluation.metrics.IBUG68_REGIONS) pooled into each column.
POOLED = {"brows": ("right_eyebrow", "left_eyebrow"), "eyes": ("right_eye", "left_eye"), "nose": ("nose",),
          "mouth": ("mouth",)}


def set_option(opts, path: str, value):
    """``opts`` (a frozen dataclass) with the field at dotted ``path`` set to ``value``."""
    head, _, rest = path.partition(".")
    names = {f.name for f in fields(opts)}
    if head not in names:
        raise SystemExit(f"unknown option {head!r} of {type(opts).__name__} (in {path!r})")
    if rest:
        inner = getattr(opts, head)
        if not is_dataclass(inner):
            raise SystemExit(f"{head} of {type(opts).__name__} is not an options class (in {path!r})")
        return replace(opts, **{head: set_option(inner, rest, value)})
    return replace(opts, **{head: value})


def parse_variant(text: str):
    """'name:a.b=1,c=None' -> (name, [(path, value), ...])."""
    name, _, spec = text.partition(":")
    pairs = []
    for item in filter(None, (s.strip() for s in spec.split(";"))):
        path, _, val = item.partition("=")
        try:
            value = ast.literal_eval(val)
        except (ValueError, SyntaxError):
            value = val  # a bare string
        pairs.append((path.strip(), value))
    return name or "base", pairs


def build_options(pairs):
    from facecorr.pipeline.correspond import CorrespondOptions

    opts = CorrespondOptions()
    for path, value in pairs:
        opts = set_option(opts, path, value)
    return opts


def _one(job):
    rec, pairs, use_gt = job
    from facecorr.evaluation import metrics
    from facecorr.io import load_mesh
    from facecorr.names import LANDMARK_NAMES
    from facecorr.pipeline import correspond
    from facecorr.template import load_template

    t0 = time.perf_counter()
    try:
        template = load_template()
        mesh = load_mesh(rec["scan"], units="mm")
        gt = metrics.load_ground_truth(rec["gt"])
        lms = {k: gt["landmarks"][k] for k in LANDMARK_NAMES} if use_gt else None
        res = correspond(mesh, landmarks=lms, template=template, options=build_options(pairs))
        reg = metrics.region_errors(res.vertices, gt["ibug68"], template)
        out = {"ok": True, "seconds": time.perf_counter() - t0, "flags": res.flags}
        for r in REGIONS:
            vals = np.concatenate([np.asarray(reg[k], float) for k in POOLED[r] if k in reg] or [np.zeros(0)])
            out[r] = float(np.mean(vals)) if len(vals) else float("nan")
        dense = metrics.dense_error(res.vertices, gt["dense"], template)
        out["dense"] = float(np.mean(dense)) if len(dense) else float("nan")
        out["landmarks"] = float(np.mean([np.linalg.norm(np.asarray(res.landmarks[k]) - gt["landmarks"][k])
                                          for k in LANDMARK_NAMES]))
        out["registered_landmarks"] = float(np.mean([np.linalg.norm(np.asarray(res.landmarks_registered[k])
                                                                    - gt["landmarks"][k]) for k in LANDMARK_NAMES]))
        out["per_landmark"] = {k: float(np.linalg.norm(np.asarray(res.landmarks[k]) - gt["landmarks"][k]))
                               for k in LANDMARK_NAMES}
        out["per_landmark_registered"] = {k: float(np.linalg.norm(np.asarray(res.landmarks_registered[k])
                                                                  - gt["landmarks"][k])) for k in LANDMARK_NAMES}
        out["weights"] = res.expression_weights
        return out
    except Exception as e:  # noqa: BLE001
        return {"ok": False, "error": f"{type(e).__name__}: {e}"}


def _one_landmarks(job):
    rec, pairs, _ = job
    from facecorr.evaluation import metrics
    from facecorr.io import load_mesh
    from facecorr.landmarks import predict_landmarks
    from facecorr.names import LANDMARK_NAMES

    t0 = time.perf_counter()
    try:
        mesh = load_mesh(rec["scan"], units="mm")
        gt = metrics.load_ground_truth(rec["gt"], load_dense=False)
        res = predict_landmarks(mesh, options=build_options(pairs).predict)
        err = {k: float(np.linalg.norm(np.asarray(res.positions[k]) - gt["landmarks"][k])) for k in LANDMARK_NAMES}
        return {"ok": True, "seconds": time.perf_counter() - t0, "flags": res.flags, "per_landmark": err,
                "landmarks": float(np.mean(list(err.values()))), "max": float(max(err.values()))}
    except Exception as e:  # noqa: BLE001
        return {"ok": False, "error": f"{type(e).__name__}: {e}", "seconds": time.perf_counter() - t0}


def landmark_table(variants, per):
    """Markdown rows: per variant the 8-landmark mean / median, T10 of the worst landmark, the
    share of scans with all 8 within 10 / 30 mm, failures and seconds per scan."""
    from facecorr.names import LANDMARK_NAMES

    print("\n| variant | mean [mm] | median scan [mm] | all 8 < 10 mm [%] | all 8 < 30 mm [%] | "
          "min T10 over landmarks [%] | per landmark mean [mm] | failed | s/scan |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, _ in variants:
        rs = per[name]
        ok = [r for r in rs if r["ok"]]
        if not ok:
            print(f"| {name} | - | - | - | - | - | - | {len(rs)} | - |")
            continue
        m = np.array([[r["per_landmark"][k] for k in LANDMARK_NAMES] for r in ok])
        t10 = 100 * (m < 10).mean(axis=0)
        print(f"| {name} | {m.mean():.2f} | {np.median(m.mean(axis=1)):.2f} | {100 * (m.max(1) < 10).mean():.1f} | "
              f"{100 * (m.max(1) < 30).mean():.1f} | {t10.min():.1f} | {' / '.join(f'{v:.2f}' for v in m.mean(0))} | "
              f"{len(rs) - len(ok)} | {np.median([r['seconds'] for r in ok]):.2f} |", flush=True)


def select(db: Path, split: str, artefacts: str | None, every: int, n: int | None):
    from facecorr.evaluation.runner import select_eval_records
    from facecorr.synth import load_index

    recs = select_eval_records(load_index(db), split=split)
    if artefacts is not None:
        kinds = set(artefacts.split(","))
        keep = []
        for r in recs:
            have = set(json.loads(Path(r["gt"]).read_text()).get("artefacts", []))
            if ("none" in kinds and not (have - {"colour"})) or (have & kinds):
                keep.append(r)
        recs = keep
    recs = recs[::max(1, every)]
    return recs[:n] if n else recs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("db", type=Path)
    ap.add_argument("--split", default="test")
    ap.add_argument("--landmarks", choices=("gt", "predicted"), default="gt")
    ap.add_argument("--variant", action="append", default=[], help="name:path=value;path=value")
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--artefacts", default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--landmarks-only", action="store_true",
                    help="predict the landmarks only (variants of the predict.* options); landmark table")
    ap.add_argument("--json", type=Path, default=None, help="write the per-scan rows here")
    a = ap.parse_args(argv)
    from facecorr.threads import process_iter

    variants = [parse_variant(v) for v in (a.variant or ["base:"])]
    for _, pairs in variants:
        build_options(pairs)  # fail early on a typo
    recs = select(a.db, a.split, a.artefacts, a.every, a.n)
    print(f"{len(recs)} scans of {a.db} ({a.split}, artefacts {a.artefacts or 'any'}), landmarks {a.landmarks}",
          flush=True)
    jobs = [(r, pairs, a.landmarks == "gt") for _, pairs in variants for r in recs]
    rows = list(process_iter(_one_landmarks if a.landmarks_only else _one, jobs, workers=a.workers, desc="variants",
                             progress=sys.stderr.isatty()))
    per = {name: rows[k * len(recs):(k + 1) * len(recs)] for k, (name, _) in enumerate(variants)}
    if a.json:
        a.json.write_text(json.dumps({"scans": [r["scan"] for r in recs], "rows": per}, indent=1, default=str))
    if a.landmarks_only:
        landmark_table(variants, per)
        return
    cols = list(REGIONS) + ["dense", "landmarks", "registered_landmarks"]
    print("\n| variant | " + " | ".join(cols) + " | median ratio to first (brows/eyes/nose/mouth/dense) | failed | s/scan |")
    print("|---|" + "---|" * (len(cols) + 3))
    first = per[variants[0][0]]
    for name, _ in variants:
        rs = per[name]
        ok = [r for r in rs if r["ok"]]
        means = [np.nanmean([r[c] for r in ok]) if ok else np.nan for c in cols]
        ratios = []
        for c in REGIONS + ("dense",):
            q = [r[c] / f[c] for r, f in zip(rs, first) if r["ok"] and f["ok"] and f[c] > 0]
            ratios.append(f"{np.nanmedian(q):.3f}" if q else "-")
        secs = np.median([r["seconds"] for r in ok]) if ok else np.nan
        print(f"| {name} | " + " | ".join(f"{m:.2f}" for m in means) + f" | {'/'.join(ratios)} | "
              f"{len(rs) - len(ok)} | {secs:.1f} |", flush=True)


if __name__ == "__main__":
    main()
