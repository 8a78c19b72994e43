"""CLI: ``facecorr landmarks SCAN --json OUT.json``."""

from __future__ import annotations


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("landmarks", help="predict the 8 landmarks of a scan",
                              description="Predict the 8 landmarks of a face scan (any pose, cropped or raw), "
                                          "refined by registering the template (--method fast: the prediction alone; --method paper: "
                                          "the paper's pipeline).")
    p.add_argument("scan", help="mesh file (PLY, OBJ, OFF, STL, WRL)")
    p.add_argument("--json", required=True, help="output JSON: units, landmarks (scan frame and units), confidence")
    p.add_argument("--model", help="landmark model .npz (default: the packaged one)")
    p.add_argument("--units", default="auto", choices=["auto", "mm", "cm", "m"])
    p.add_argument("--method", default="default", choices=["default", "fast", "paper"],
                   help="default: predicted, then refined by registering the template; fast: the prediction alone "
                        "(local template-patch fits, ~1 s; the refinement is ~2-3x more accurate for ~1-2 s more); "
                        "paper: the paper's pipeline alone (umbilics, FP + PCA labels, nose-first search, belief "
                        "propagation; ~6 s)")
    p.add_argument("--fast", action="store_true", help="the same as --method fast")
    p.set_defaults(func=cmd_landmarks)


def landmarks_json(result, mesh) -> dict:
    """The `facecorr landmarks` JSON contract (README): positions in the scan's frame and units, plus confidence."""
    return {
        "units": mesh.units,
        "landmarks": {k: mesh.to_source_units(v).tolist() for k, v in result.positions.items()},
        "confidence": {k: round(float(v), 4) for k, v in result.confidence.items()},
        "flags": list(result.flags),
        "timings_s": {k: round(float(v), 4) for k, v in result.timings_s.items()},
    }


def cmd_landmarks(args) -> int:
    from ..io.atomic import write_json
    from ..io import load_mesh
    from ..io.atomic import check_output_paths
    from dataclasses import replace

    from ..evaluation.landmarks import METHODS
    from ..pipeline.correspond import CorrespondOptions
    from ..pipeline.landmarks import locate_landmarks

    check_output_paths([("--json", args.json)], inputs=[args.scan])
    mesh = load_mesh(args.scan, units=args.units)
    predict, refine = METHODS["fast" if args.fast else args.method]
    opts = CorrespondOptions()
    result = locate_landmarks(mesh, model=args.model, refine=refine,
                              options=replace(opts, predict=replace(opts.predict, **predict)))
    write_json(args.json, landmarks_json(result, mesh))
    for f in result.flags:
        print(f"warning: {f}")
    return 0
