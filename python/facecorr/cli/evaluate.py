"""CLI: ``facecorr eval registration`` (paper Table 3, Fig. 10) and ``facecorr eval landmarks``
(paper Tables 1/2) on a synthetic database."""

from __future__ import annotations

from .common import add_run_options, open_log


def add_commands(sub) -> None:
    e = sub.add_parser("eval", help="evaluate on a synthetic database (paper Tables 1-3, Fig. 10)")
    esub = e.add_subparsers(dest="eval_what", metavar="WHAT", required=True)
    er = esub.add_parser("registration", help="Table 3 region errors, MHD, dense error, cumulative curve")
    er.add_argument("db", help="synthetic database folder (with index.json)")
    er.add_argument("--out", default="out/eval_registration", help="report folder")
    er.add_argument("--gt-landmarks", action="store_true", help="guide by the ground-truth landmarks instead of predicted ones")
    er.add_argument("--workers", type=int, default=2)
    er.add_argument("--limit", type=int, help="only the first N evaluation scans")
    er.add_argument("--split", default="test",
                    help="subjects to evaluate: test (default), train, or ood_test / ood_holdout on a bu3dfe-ood database")
    add_run_options(er)
    er.set_defaults(func=cmd_eval_registration)

    e = esub.add_parser("landmarks", help="paper Tables 1/2: per-landmark errors and detection rates")
    e.add_argument("db", help="synthetic database folder (with index.json)")
    e.add_argument("--model", help="landmark model .npz (default: the packaged one)")
    e.add_argument("--out", default="out/eval_landmarks", help="report folder")
    e.add_argument("--workers", type=int, default=2)
    e.add_argument("--limit", type=int, help="only the first N evaluation scans")
    e.add_argument("--split", default="test",
                   help="subjects to evaluate: test (default), train, or ood_test / ood_holdout on a bu3dfe-ood database")
    e.add_argument("--rotate", action="store_true", help="turn every scan by a random rotation first")
    e.add_argument("--method", default="default", choices=["default", "fast", "paper"],
                   help="default (what `facecorr landmarks` writes: protrusion start + template patches, refined by "
                        "the registration), fast (the prediction alone, `facecorr landmarks --fast`) or paper "
                        "(umbilic/FPPCA start + BP)")
    e.add_argument("--no-png", action="store_true", help="skip landmarks.png (true vs predicted on 8 scans)")
    add_run_options(e)
    e.set_defaults(func=cmd_eval_landmarks)


#: Per-scan fields of each evaluation's rows that its --log lines carry.
_LOGGED = {
    "registration": ("seconds", "mhd", "dense_mean", "landmark_errors", "timings_s", "error"),
    "landmarks": ("seconds", "errors", "confidence", "flags", "timings_s", "error"),
}


def _logger(log, what):
    """on_row for an evaluation: one --log line per scan (None without --log)."""
    if log is None:
        return None

    def write(row):
        log.write({"scan": row["scan"], "status": "ok" if row["ok"] else "failed",
                   **{k: row[k] for k in _LOGGED[what] if row.get(k) is not None}})

    return write


def _failed_lines(rows) -> None:
    import sys

    for r in rows:
        if not r["ok"]:
            print(f"  {r['scan']}: {r['error']}", file=sys.stderr)


def cmd_eval_registration(args) -> int:
    from ..evaluation.registration import evaluate_registration

    log = open_log(args)
    try:
        rows = evaluate_registration(args.db, args.out, use_gt_landmarks=args.gt_landmarks,
                                     workers=args.workers, limit=args.limit, split=args.split, progress=not args.quiet,
                                     on_row=_logger(log, "registration"), quiet=args.quiet)
    finally:
        if log is not None:
            log.close()
    if args.quiet:
        _failed_lines(rows)
    return 0 if all(r["ok"] for r in rows) else 1


def cmd_eval_landmarks(args) -> int:
    from ..evaluation.landmarks import evaluate_landmarks

    log = open_log(args)
    try:
        _, rows, md = evaluate_landmarks(args.db, args.out, model=args.model, workers=args.workers,
                                         limit=args.limit, rotate=args.rotate, method=args.method,
                                         png=not args.no_png, progress=not args.quiet, split=args.split,
                                         on_row=_logger(log, "landmarks"))
    finally:
        if log is not None:
            log.close()
    if args.quiet:
        _failed_lines(rows)
    else:
        print(md)
    return 0 if all(r["ok"] for r in rows) else 1
