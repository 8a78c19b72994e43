"""CLI: ``facecorr synth OUT_DIR --preset tiny|bu3dfe --seed N ...``."""

from __future__ import annotations

import sys
import time

from .common import add_run_options, open_log


def add_commands(subparsers) -> None:
    p = subparsers.add_parser(
        "synth", help="generate a BU-3DFE-like synthetic scan database with exact ground truth",
        description="Simulate range scans of ICT-model faces (7 expressions x 4 levels) with exact "
                    "landmark, iBUG-68 and dense ground truth; BU-3DFE file layout.",
    )
    p.add_argument("out_dir", help="output folder (created)")
    p.add_argument("--preset", choices=("tiny", "bu3dfe", "bu3dfe-ood"), default="tiny",
                   help="tiny = 2 subjects, bu3dfe = 100 (x 25 scans), bu3dfe-ood = 30 out-of-model subjects with "
                        "the artefacts of real scans (test-only: splits ood_test / ood_holdout)")
    p.add_argument("--seed", type=int, default=0, help="database seed (bitwise reproducible), default 0")
    p.add_argument("--workers", type=int, default=2, help="worker processes, default 2 (output does not depend on it)")
    p.add_argument("--crop", choices=("face", "none"), default=None, help="face = cropped like BU-3DFE, none = raw scan")
    p.add_argument("--subjects", type=int, default=None, help="override the preset's number of subjects")
    p.add_argument("--subset", choices=("all", "eval"), default="all", help="eval = NE + 6 expressions at level 4")
    p.add_argument("--expressions", default=None, help="comma-separated codes, e.g. NE,HA,SU (default all)")
    p.add_argument("--levels", default=None, help="comma-separated levels 1..4 (default all)")
    p.add_argument("--yaw", type=float, default=None, help="max |yaw| of the random pose, degrees (default 45)")
    p.add_argument("--pitch", type=float, default=None, help="max |pitch|, degrees (default 30)")
    p.add_argument("--roll", type=float, default=None, help="max |roll|, degrees (default 30)")
    p.add_argument("--any-rotation", action="store_true", help="uniformly random rotation instead of yaw/pitch/roll ranges")
    p.add_argument("--colour", choices=("vertex", "texture"), default=None,
                   help="also colour the scans (a smooth skin pattern with exact ground truth): vertex = PLY with "
                        "per-vertex RGB, texture = OBJ + MTL + PNG")
    p.add_argument("--preview", metavar="PNG", default=None, help="also write a contact sheet of the first subject")
    add_run_options(p)
    p.set_defaults(func=run_synth)


def run_synth(args) -> int:
    from ..synth.generate import generate, load_index
    from ..synth.preview import contact_sheet

    opts = {k: getattr(args, k) for k in ("yaw", "pitch", "roll") if getattr(args, k) is not None}
    if args.any_rotation:
        opts["uniform_rotation"] = True
    t0 = time.perf_counter()
    log = open_log(args)
    try:
        recs = generate(
            args.out_dir, preset=args.preset, seed=args.seed, workers=args.workers, crop=args.crop or "face",
            subjects=args.subjects, subset=args.subset,
            expressions=args.expressions.split(",") if args.expressions else None,
            levels=args.levels.split(",") if args.levels else None,
            progress=not args.quiet, colour=args.colour, on_scan=None if log is None else log.write, **opts,
        )
    finally:
        if log is not None:
            log.close()
    dt = time.perf_counter() - t0
    if not args.quiet:
        print(f"{len(recs)} scans in {dt:.1f} s -> {args.out_dir}/index.json", file=sys.stderr)
    if args.preview:
        allr = load_index(args.out_dir)
        first = allr[0]["subject"]
        mine = [r for r in allr if r["subject"] == first]
        top = {}
        for r in mine:  # one panel per expression, its highest level
            if r["expression"] not in top or r["level"] > top[r["expression"]]["level"]:
                top[r["expression"]] = r
        contact_sheet(list(top.values()), args.preview, title=f"{first}: highest level per expression (red: 8 landmarks, blue: iBUG-68)")
        if not args.quiet:
            print(f"preview -> {args.preview}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    """Run the synth command alone (``python -m facecorr.synth.commands OUT ...``)."""
    import argparse

    from ..errors import FacecorrError

    ap = argparse.ArgumentParser(prog="facecorr")
    sub = ap.add_subparsers(dest="command", required=True)
    add_commands(sub)
    args = ap.parse_args(["synth", *(sys.argv[1:] if argv is None else argv)])
    try:
        return args.func(args)
    except FacecorrError as e:
        print(f"facecorr synth: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
