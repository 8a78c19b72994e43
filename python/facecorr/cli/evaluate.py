"""CLI: ``facecorr eval registration`` (paper Table 3, Fig. 10) and ``facecorr eval landmarks``
(paper Tables 1/2) on a synthetic database."""

from __future__ import annotations


def add_commands(sub) -> None:
    e = sub.add_parser("eval", help="evaluate on a synthetic database (paper Tables 1-3, Fig. 10)")
    esub = e.add_subparsers(dest="eval_what", metavar="WHAT", required=True)
    er = esub.add_parser("registration", help="Table 3 region errors, MHD, dense error, cumulative curve")
    er.add_argument("db", help="synthetic database folder (with index.json)")
    er.add_argument("--out", default="out/eval_registration", help="report folder")
    er.add_argument("--gt-landmarks", action="store_true", help="guide by the ground-truth landmarks instead of predicted ones")
    er.add_argument("--workers", type=int, default=2)
    er.add_argument("--limit", type=int, help="only the first N evaluation scans")
    er.set_defaults(func=cmd_eval_registration)

    e = esub.add_parser("landmarks", help="paper Tables 1/2: per-landmark errors and detection rates")
    e.add_argument("db", help="synthetic database folder (with index.json)")
    e.add_argument("--model", help="landmark model .npz (default: the packaged one)")
    e.add_argument("--out", default="out/eval_landmarks", help="report folder")
    e.add_argument("--workers", type=int, default=2)
    e.add_argument("--limit", type=int, help="only the first N evaluation scans")
    e.add_argument("--rotate", action="store_true", help="turn every scan by a random rotation first")
    e.add_argument("--method", default="default", choices=["default", "paper"],
                   help="default (protrusion start + template patches) or paper (umbilic/FPPCA start + BP)")
    e.add_argument("--no-png", action="store_true", help="skip landmarks.png (true vs predicted on 8 scans)")
    e.set_defaults(func=cmd_eval_landmarks)


def cmd_eval_registration(args) -> int:
    from ..evaluation.registration import evaluate_registration

    rows = evaluate_registration(args.db, args.out, use_gt_landmarks=args.gt_landmarks,
                                 workers=args.workers, limit=args.limit)
    return 0 if all(r["ok"] for r in rows) else 1


def cmd_eval_landmarks(args) -> int:
    from ..evaluation.landmarks import evaluate_landmarks

    _, rows, md = evaluate_landmarks(args.db, args.out, model=args.model, workers=args.workers,
                                     limit=args.limit, rotate=args.rotate, method=args.method,
                                     png=not args.no_png)
    print(md)
    return 0 if all(r["ok"] for r in rows) else 1
