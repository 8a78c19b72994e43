"""CLI: ``facecorr train``, ``facecorr landmarks``, ``facecorr eval landmarks``."""

from __future__ import annotations


def add_commands(subparsers) -> None:
    t = subparsers.add_parser("train", help="train the landmark model on a synthetic database",
                              description="Train the landmark model (FP node potentials, canonical-form edge "
                                          "potentials, FPPCA ellipsoids) on the database's training split.")
    t.add_argument("db", help="synthetic database folder (with index.json)")
    t.add_argument("--out", required=True, help="model file to write (.npz)")
    t.add_argument("--neutral-only", action="store_true", help="train on neutral scans only (Tn); default all (Te)")
    t.add_argument("--workers", type=int, default=2)
    t.set_defaults(func=cmd_train)

    p = subparsers.add_parser("landmarks", help="predict the 8 landmarks of a scan",
                              description="Predict the 8 landmarks of a face scan (any pose, cropped or raw).")
    p.add_argument("scan", help="mesh file (PLY, OBJ, OFF, STL, WRL)")
    p.add_argument("--json", required=True, help="output JSON: units, landmarks (scan frame and units), confidence")
    p.add_argument("--model", help="landmark model .npz (default: the packaged one)")
    p.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"])
    p.set_defaults(func=cmd_landmarks)

    from .. import commands as core_commands

    esub = core_commands.EVAL_SUBPARSERS
    if esub is not None:
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


def cmd_train(args) -> int:
    from .train import train

    model = train(args.db, args.out, neutral_only=args.neutral_only, workers=args.workers)
    print(f"wrote {args.out} ({model.params['n_scans']} scans, {model.params['n_failed']} failed)")
    return 0


def landmarks_json(result, mesh) -> dict:
    """The DESIGN.md contract: positions in the scan's frame and units, plus confidence."""
    return {
        "units": mesh.units,
        "landmarks": {k: mesh.to_source_units(v).tolist() for k, v in result.positions.items()},
        "confidence": {k: round(float(v), 4) for k, v in result.confidence.items()},
        "flags": list(result.flags),
        "timings_s": {k: round(float(v), 4) for k, v in result.timings_s.items()},
    }


def cmd_landmarks(args) -> int:
    from ..fileio import write_json
    from ..io import load_mesh
    from .predict import predict_landmarks

    mesh = load_mesh(args.scan, units=args.units)
    result = predict_landmarks(mesh, model=args.model)
    write_json(args.json, landmarks_json(result, mesh))
    for f in result.flags:
        print(f"warning: {f}")
    return 0


def cmd_eval_landmarks(args) -> int:
    from .evaluate import evaluate_landmarks

    _, rows, md = evaluate_landmarks(args.db, args.out, model=args.model, workers=args.workers,
                                     limit=args.limit, rotate=args.rotate, method=args.method,
                                     png=not args.no_png)
    print(md)
    return 0 if all(r["ok"] for r in rows) else 1
