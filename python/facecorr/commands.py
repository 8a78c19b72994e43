"""CLI commands of the pipeline: ``register``, ``batch``, ``train-identity``, ``demo``, ``eval registration``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

SCAN_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".wrl")


def add_commands(sub) -> None:
    p = sub.add_parser("register", help="register the template onto one scan",
                       description="Predict the 8 landmarks, then fit the blendshape template "
                                   "(affine, expression, shape). Writes the template mesh deformed "
                                   "onto the scan, in the scan's frame and units.")
    p.add_argument("scan", help="scan file (.ply .obj .stl .off .glb .wrl)")
    p.add_argument("-o", "--output", required=True, help="registered template mesh to write (.ply, .obj, ...)")
    p.add_argument("--json", help="also write landmarks, expression weights, MHD, timings as JSON")
    p.add_argument("--landmarks", help="JSON of the 8 landmarks (as `facecorr landmarks` writes) to use instead of predicting")
    p.add_argument("--png", help="also write a picture: scan beside the registered template coloured by distance")
    p.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"], help="the scan's units (default: infer)")
    p.set_defaults(func=cmd_register)

    b = sub.add_parser("batch", help="register every scan in a folder (resumable)",
                       description="Register every scan under INPUT_DIR into OUTPUT_DIR (same relative "
                                   "paths, .ply + .json). A bad scan is reported and skipped; finished "
                                   "results are kept, so a rerun only does what is missing.")
    b.add_argument("input_dir")
    b.add_argument("output_dir")
    b.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    b.add_argument("--png", action="store_true", help="also write a PNG per scan")
    b.add_argument("--overwrite", action="store_true", help="redo scans that already have results")
    b.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"])
    b.set_defaults(func=cmd_batch)

    ti = sub.add_parser("train-identity", help="learn the identity basis fitted with the expression",
                        description="PCA of the template's shape on every training scan of a synthetic "
                                    "database (from its dense ground truth); see facecorr.registration.identity.")
    ti.add_argument("db", help="synthetic database folder (with index.json and *_dense.npz)")
    ti.add_argument("--out", required=True, help="basis file to write (.npz)")
    ti.add_argument("--modes", type=int, default=40, help="modes kept (default 40)")
    ti.add_argument("--neutral-only", action="store_true", help="learn from the neutral scans only")
    ti.set_defaults(func=cmd_train_identity)

    d = sub.add_parser("demo", help="synthesise a scan and run the whole pipeline on it")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.add_argument("--seed", type=int, default=7)
    d.set_defaults(func=cmd_demo)

    e = sub.add_parser("eval", help="evaluate on a synthetic database (paper Tables 1-3, Fig. 10)")
    esub = e.add_subparsers(dest="eval_what", metavar="WHAT", required=True)
    er = esub.add_parser("registration", help="Table 3 region errors, MHD, dense error, cumulative curve")
    er.add_argument("db", help="synthetic database folder (with index.json)")
    er.add_argument("--out", default="out/eval_registration", help="report folder")
    er.add_argument("--gt-landmarks", action="store_true", help="guide by the ground-truth landmarks instead of predicted ones")
    er.add_argument("--workers", type=int, default=2)
    er.add_argument("--limit", type=int, help="only the first N evaluation scans")
    er.set_defaults(func=cmd_eval_registration)
    # `facecorr eval landmarks` is contributed by facecorr.landmarks.commands through this hook.
    global EVAL_SUBPARSERS
    EVAL_SUBPARSERS = esub


#: The ``eval`` sub-command's sub-parsers, for other command modules to add to.
EVAL_SUBPARSERS = None


def cmd_train_identity(args) -> int:
    from .errors import FacecorrError
    from .registration.identity import train_identity_basis

    if not (Path(args.db) / "index.json").is_file():
        raise FacecorrError(f"{args.db}: not a synthetic database (no index.json)")
    try:
        basis = train_identity_basis(args.db, n_modes=args.modes, neutral_only=args.neutral_only)
    except ValueError as e:
        raise FacecorrError(str(e)) from None
    basis.save(args.out)
    print(f"wrote {args.out} ({basis.n_modes} modes from {basis.n_samples} scans, "
          f"{100 * basis.explained.sum():.1f} % of the variance)")
    return 0


def cmd_eval_registration(args) -> int:
    from .registration_eval import evaluate_registration

    rows = evaluate_registration(args.db, args.out, use_gt_landmarks=args.gt_landmarks,
                                 workers=args.workers, limit=args.limit)
    return 0 if all(r["ok"] for r in rows) else 1


def _read_landmarks_json(path, mesh) -> dict:
    """Landmarks from a JSON ({"units": u, "landmarks": {name: xyz}}) converted to mm."""
    from .errors import LandmarkError
    from .io import UNIT_TO_MM

    try:
        data = json.loads(Path(path).read_text())
        lms = data["landmarks"]
        factor = UNIT_TO_MM[data["units"]] if "units" in data else mesh.to_mm
        return {k: [float(c) * factor for c in v] for k, v in lms.items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise LandmarkError(f"{path}: not a landmarks JSON ({type(e).__name__}: {e})") from None


def register_file(scan_path, out_mesh, out_json=None, png=None, units="auto", landmarks_json=None):
    """Load, register and write one scan. Returns the Result (raises FacecorrError on bad input)."""
    from .io import load_mesh
    from .pipeline import correspond, plot_registration

    mesh = load_mesh(scan_path, units=units)
    lms = _read_landmarks_json(landmarks_json, mesh) if landmarks_json else None
    result = correspond(mesh, landmarks=lms)
    result.save(out_mesh, out_json)
    if png:
        plot_registration(mesh, result, png, title=Path(scan_path).name)
    return result


def cmd_register(args) -> int:
    result = register_file(args.scan, args.output, args.json, args.png, args.units, args.landmarks)
    print(f"{args.output}: MHD {result.mhd:.3f} mm, {result.timings_s['total']:.2f} s"
          + (f"; warnings: {'; '.join(result.flags)}" if result.flags else ""))
    return 0


def _batch_one(job):
    """Worker: register one scan; never raises (returns a status row)."""
    scan, out_mesh, out_json, png, units = job
    t0 = time.perf_counter()
    try:
        register_file(scan, out_mesh, out_json, png, units)
        return {"scan": str(scan), "ok": True, "seconds": round(time.perf_counter() - t0, 3)}
    except Exception as e:  # noqa: BLE001 - one bad scan must not stop the batch
        from .errors import FacecorrError

        kind = "bad input" if isinstance(e, FacecorrError) else f"internal error ({type(e).__name__})"
        return {"scan": str(scan), "ok": False, "error": f"{kind}: {str(e).splitlines()[0] if str(e) else ''}"}


def cmd_batch(args) -> int:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from tqdm import tqdm

    from .errors import FacecorrError
    from .threads import spawn_context
    from .fileio import write_json

    src, dst = Path(args.input_dir), Path(args.output_dir)
    if not src.is_dir():
        raise FacecorrError(f"{src}: not a folder")
    scans = sorted(p for p in src.rglob("*") if p.suffix.lower() in SCAN_SUFFIXES and p.is_file())
    if not scans:
        raise FacecorrError(f"{src}: no scan files ({', '.join(SCAN_SUFFIXES)})")
    jobs, skipped = [], 0
    for s in scans:
        rel = s.relative_to(src)
        out_mesh = dst / rel.with_suffix(".ply")
        out_json = out_mesh.with_suffix(".json")
        if not args.overwrite and out_mesh.exists() and out_json.exists():
            skipped += 1
            continue
        png = out_mesh.with_suffix(".png") if args.png else None
        jobs.append((s, out_mesh, out_json, png, args.units))
    rows = []
    failures_path = dst / "failures.json"
    with ProcessPoolExecutor(max_workers=max(1, args.workers), mp_context=spawn_context()) as pool:
        futures = [pool.submit(_batch_one, j) for j in jobs]
        for fut in tqdm(as_completed(futures), total=len(futures), desc="registering", unit="scan"):
            rows.append(fut.result())
            failed = [r for r in rows if not r["ok"]]
            if failed:
                write_json(failures_path, failed)
    failed = [r for r in rows if not r["ok"]]
    done = len(rows) - len(failed)
    print(f"{done} registered, {skipped} already done, {len(failed)} failed"
          + (f" (see {failures_path})" if failed else ""))
    for r in failed:
        print(f"  {r['scan']}: {r['error']}", file=sys.stderr)
    return 2 if failed else 0


def _demo_report(result, gt, label) -> None:
    """Print a registration's errors against the synthetic ground truth."""
    from . import evaluate

    lm_err = {k: float(((result.landmarks[k] - gt["landmarks"][k]) ** 2).sum() ** 0.5) for k in result.landmarks}
    regions = evaluate.region_errors(result.vertices, gt["ibug68"])
    dense = evaluate.dense_error(result.vertices, gt["dense"])
    print(f"      {label}:")
    print(f"        landmarks used: mean error {sum(lm_err.values()) / len(lm_err):.2f} mm, max {max(lm_err.values()):.2f} mm")
    print("        region mean errors [mm]: " + ", ".join(f"{k} {e.mean():.2f}" for k, e in regions.items()))
    print(f"        dense correspondence error {dense.mean():.2f} mm over {len(dense)} scan points; "
          f"MHD {result.mhd:.3f} mm; {result.timings_s['total']:.2f} s")


def cmd_demo(args) -> int:
    """Synthesise one scan in a random pose and register it fully automatically; as the scan is
    synthetic, also register it guided by its true landmarks and compare both with the truth."""
    from . import evaluate
    from .io import load_mesh
    from .names import LANDMARK_NAMES
    from .pipeline import correspond, plot_registration
    from .synth import generate_scan

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"[1/4] synthesising a scan (subject F0001, happiness level 4, random pose) into {out}/scan")
    rec = generate_scan(out / "scan", subject=1, expression="HA", level=4, seed=args.seed)
    mesh = load_mesh(rec["scan"])
    gt = evaluate.load_ground_truth(rec["gt"])
    print(f"      {mesh.n_vertices} vertices, {mesh.n_faces} triangles")
    print("[2/4] fully automatic: predicting landmarks, registering the template")
    result = correspond(mesh)
    result.save(out / "registered.ply", out / "result.json")
    plot_registration(mesh, result, out / "registration.png", title="facecorr demo: fully automatic")
    for f in result.flags:
        print(f"      warning: {f}")
    print("[3/4] the same scan guided by its ground-truth landmarks (registration stage alone)")
    guided = correspond(mesh, landmarks={k: gt["landmarks"][k] for k in LANDMARK_NAMES})
    guided.save(out / "registered_gt_landmarks.ply", out / "result_gt_landmarks.json")
    plot_registration(mesh, guided, out / "registration_gt_landmarks.png", title="facecorr demo: true landmarks")
    print("[4/4] errors against the ground truth")
    _demo_report(result, gt, "fully automatic")
    _demo_report(guided, gt, "with the true landmarks")
    print(f"wrote {out}/registered.ply, result.json, registration.png (and *_gt_landmarks.*)")
    return 0
