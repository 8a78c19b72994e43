"""CLI: ``facecorr register``, ``facecorr batch`` and ``facecorr demo`` (the pipeline on one scan,
a folder, a synthetic demo scan)."""

from __future__ import annotations

import sys
from pathlib import Path

from .common import add_run_options, open_log


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
    p.add_argument("--neutral", metavar="OUT_NEUTRAL", help="also write the expression-removed shape (the registered "
                   "template with the fitted expression taken away; same vertex order, scan's frame and units)")
    p.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"], help="the scan's units (default: infer)")
    p.add_argument("--landmark-set", metavar="FILE", help="JSON of your own points on the template ({name: vertex id or "
                   "{\"face\": id, \"bary\": [b0, b1, b2]}}), read off the result into the JSON's point_set")
    p.set_defaults(func=cmd_register)

    b = sub.add_parser("batch", help="register every scan in a folder (resumable)",
                       description="Register every scan under INPUT_DIR into OUTPUT_DIR (same relative "
                                   "paths, .ply + .json, + .png with --png, + _neutral.ply with --neutral). A bad scan "
                                   "is reported and skipped; finished results are kept, so a rerun only does the scans "
                                   "that miss one of their files (each scan's files are written together, all or "
                                   "none).")
    b.add_argument("input_dir")
    b.add_argument("output_dir")
    b.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    b.add_argument("--png", action="store_true", help="also write a small PNG per scan (the report's thumbnail: the scan "
                   "with the landmarks used beside the registered template coloured by distance to the scan)")
    b.add_argument("--neutral", action="store_true", help="also write <stem>_neutral.ply per scan: the expression-"
                   "removed shape (the registered template with its fitted expression taken away; same vertex order, "
                   "scan's frame and units), as `model build --neutral` reads it. A rerun with --neutral over results "
                   "without it registers those scans again")
    b.add_argument("--overwrite", action="store_true", help="redo scans that already have results")
    b.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"])
    b.add_argument("--landmark-set", metavar="FILE", help="your own points on the template, read off every result")
    b.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster: 'local' (a LocalCluster of --workers processes), a scheduler "
                        "address (tcp://host:8786) or a scheduler file (.json); needs facecorr[dask]. The workers "
                        "read the scans at the paths this machine sees (a shared filesystem) unless --ship-bytes; "
                        "this process writes the results")
    b.add_argument("--ship-bytes", action="store_true",
                   help="with --scheduler: send each scan's bytes to the workers (no shared filesystem needed)")
    add_run_options(b)
    b.set_defaults(func=cmd_batch)

    x = sub.add_parser("export-points", help="the iBUG-68 points and landmarks of a batch's results, in one table",
                       description="Read every result JSON under RESULTS (from `facecorr batch` or "
                                   "`facecorr register --json`) and write one table of their points (iBUG-68 and the 8 "
                                   "landmarks, scan frame and units): CSV (scan,point,x,y,z,units) or JSON.")
    x.add_argument("results", help="folder of results")
    x.add_argument("-o", "--output", required=True, help="table to write (.csv or .json)")
    x.set_defaults(func=cmd_export_points)

    d = sub.add_parser("demo", help="synthesise a scan and run the whole pipeline on it")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.add_argument("--seed", type=int, default=7)
    d.set_defaults(func=cmd_demo)


def cmd_register(args) -> int:
    from ..pipeline.batch import register_file

    result = register_file(args.scan, args.output, args.json, args.png, args.units, args.landmarks,
                           point_set=args.landmark_set, neutral=args.neutral)
    print(f"{args.output}: MHD {result.mhd:.3f} mm, {result.timings_s['total']:.2f} s"
          + (f"; warnings: {'; '.join(result.flags)}" if result.flags else ""))
    return 0


def _read_failures(path: Path) -> list:
    """The rows of an earlier run's failures.json ([] if none or unreadable)."""
    import json

    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return [r for r in rows if isinstance(r, dict) and "scan" in r] if isinstance(rows, list) else []


def _write_failures(path: Path, rows: list) -> None:
    """failures.json holds exactly ``rows``; none: the file is removed."""
    from ..io.atomic import write_json

    if rows:
        write_json(path, rows)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def cmd_batch(args) -> int:
    from contextlib import ExitStack

    from ..errors import FacecorrError
    from ..io.atomic import remove_stale_temps
    from ..pipeline.batch import FAILURES_NAME, plan_batch, register_job
    from ..threads import process_iter

    dst = Path(args.output_dir)
    if args.ship_bytes and not args.scheduler:
        raise FacecorrError("--ship-bytes needs --scheduler (the local batch reads the scans itself)")
    points = None
    if args.landmark_set:  # checked once, up front: a bad file is one error, not one per scan
        from ..template import load_template
        from ..template.point_sets import read_point_set

        points = read_point_set(args.landmark_set, load_template())
    jobs, skipped = plan_batch(Path(args.input_dir), dst, overwrite=args.overwrite, png=args.png, units=args.units,
                               point_set=args.landmark_set, neutral=args.neutral)
    failures_path = dst / FAILURES_NAME
    pending = {str(j[0]): j for j in jobs}
    # an earlier run's failures stay recorded until their scan is tried again (a scan with
    # results is not a failure: it is no job and its old row is dropped)
    earlier = [r for r in _read_failures(failures_path) if r["scan"] in pending]
    rows = []

    def failures() -> list:
        done = {r["scan"] for r in rows}
        return [r for r in earlier if r["scan"] not in done] + \
               [{k: r[k] for k in ("scan", "ok", "error")} for r in rows if not r["ok"]]

    with ExitStack() as stack:
        log = open_log(args, inputs=[j[0] for j in jobs])
        if log is not None:
            stack.enter_context(log)
        if args.scheduler and jobs:  # (nothing left to do: no cluster to start)
            from ..pipeline.cluster import cluster_results, connect

            client = stack.enter_context(connect(args.scheduler, workers=max(1, args.workers)))
            gen = cluster_results(jobs, client, ship_bytes=args.ship_bytes, points=points, progress=not args.quiet)
        else:
            gen = process_iter(register_job, jobs, workers=max(1, args.workers), desc="registering", ordered=False,
                               progress=not args.quiet)
        try:
            for row in gen:
                rows.append(row)
                if log is not None:
                    log.write(_log_line(row))
                if not row["ok"]:
                    _write_failures(failures_path, failures())
        finally:
            gen.close()  # on Ctrl-C / SIGTERM: queued jobs cancelled, running workers stopped
            for job in jobs:
                for p in job.outputs:
                    remove_stale_temps(p)
            if failures() or failures_path.exists():
                _write_failures(failures_path, failures())
    failed = [r for r in rows if not r["ok"]]
    done = len(rows) - len(failed)
    if not args.quiet:
        print(f"{done} registered, {skipped} already done, {len(failed)} failed"
              + (f" (see {failures_path})" if failed else ""))
    for r in failed:
        print(f"  {r['scan']}: {r['error']}", file=sys.stderr)
    return 2 if failed else 0


def _log_line(row: dict) -> dict:
    """The --log line of a batch row: scan, status, seconds, mhd, coverage, flags, timings_s, error, worker."""
    line = {"scan": row["scan"], "status": "ok" if row["ok"] else "failed"}
    for k in ("seconds", "mhd", "coverage", "flags", "timings_s", "error", "worker"):
        if row.get(k) is not None:
            line[k] = row[k]
    return line


def _demo_report(result, gt, label) -> None:
    """Print a registration's errors against the synthetic ground truth."""
    from ..evaluation import metrics as evaluate

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
    from ..evaluation import metrics as evaluate
    from ..io import load_mesh
    from ..names import LANDMARK_NAMES
    from ..pipeline import correspond
    from ..render import plot_registration
    from ..synth import generate_scan
    from ..template import load_template

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
    plot_registration(mesh, result, out / "registration.png", load_template(), title="facecorr demo: fully automatic")
    for f in result.flags:
        print(f"      warning: {f}")
    print("[3/4] the same scan guided by its ground-truth landmarks (registration stage alone)")
    guided = correspond(mesh, landmarks={k: gt["landmarks"][k] for k in LANDMARK_NAMES})
    guided.save(out / "registered_gt_landmarks.ply", out / "result_gt_landmarks.json")
    plot_registration(mesh, guided, out / "registration_gt_landmarks.png", load_template(),
                      title="facecorr demo: true landmarks")
    print("[4/4] errors against the ground truth")
    _demo_report(result, gt, "fully automatic")
    _demo_report(guided, gt, "with the true landmarks")
    print(f"wrote {out}/registered.ply, result.json, registration.png (and *_gt_landmarks.*)")
    return 0


def cmd_export_points(args) -> int:
    import csv
    import io as text_io

    from ..errors import FacecorrError
    from ..io.atomic import write_json, write_text
    from ..pipeline.batch import collect_points

    out = Path(args.output)
    if out.suffix.lower() not in (".csv", ".json"):
        raise FacecorrError(f"{out}: the table must be .csv or .json")
    if out.is_dir():
        raise FacecorrError(f"{out}: is a folder")
    rows = collect_points(args.results)
    if out.suffix.lower() == ".json":
        write_json(out, rows)
    else:
        buf = text_io.StringIO()
        w = csv.DictWriter(buf, fieldnames=["scan", "point", "x", "y", "z", "units"], lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        write_text(out, buf.getvalue())
    print(f"{out}: {len(rows)} points of {len({r['scan'] for r in rows})} scans")
    return 0
