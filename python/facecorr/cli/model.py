"""CLI: ``facecorr model build | show | export | eval`` (statistical shape models of a batch's
results; :mod:`facecorr.model`)."""

from __future__ import annotations

from pathlib import Path


def _share(text: str) -> float:
    import argparse

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a share in (0, 1], got {text}")
    return v


def _positive(text: str) -> int:
    import argparse

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _add_fit_options(p) -> None:
    """The options of a model's fit, shared by build and eval."""
    import argparse

    p.add_argument("--neutral", action="store_true",
                   help="use the expression-removed shapes <stem>_neutral.ply (batch --neutral): an identity model")
    k = p.add_mutually_exclusive_group()
    k.add_argument("--modes", type=_positive, metavar="K", help="keep K modes")
    k.add_argument("--variance", type=_share, default=0.98, metavar="SHARE",
                   help="keep the fewest modes explaining this share of the variance (default 0.98)")
    p.add_argument("--scale", action=argparse.BooleanOptionalAction, default=False,
                   help="similarity alignment: remove each face's size too (default: --no-scale, rigid: size "
                        "stays part of the shape)")
    p.add_argument("--include-flagged", action="store_true",
                   help="also use results whose flags doubt the registration (implausible fit, low coverage, "
                        "several pieces, a landmark off the scan, failed face fit); they are skipped by default")


def add_commands(sub) -> None:
    m = sub.add_parser("model", help="statistical shape models of registered scans (build, show, export, eval)",
                       description="Statistical shape models from the results of `facecorr batch`: Procrustes "
                                   "alignment, then PCA.")
    msub = m.add_subparsers(dest="model_what", metavar="WHAT", required=True)

    b = msub.add_parser("build", help="fit a shape model to a folder of results",
                        description="Read every result under RESULTS (<stem>.ply + <stem>.json from `facecorr "
                                    "batch`), convert it to mm, align all by generalized Procrustes and fit a PCA. "
                                    "Writes an npz: mean (N, 3) mm, components (K, N, 3) orthonormal, variances (K,) "
                                    "descending, n_scans, faces, names.")
    b.add_argument("results", help="folder of results (the output folder of `facecorr batch`)")
    b.add_argument("-o", "--output", required=True, help="model file to write (.npz)")
    _add_fit_options(b)
    b.add_argument("--scheduler", metavar="ADDRESS",
                   help="build on a Dask cluster: 'local' (a LocalCluster of --workers processes), a scheduler address "
                        "(tcp://host:8786) or a scheduler file (.json); needs facecorr[dask]. The workers read the "
                        "result meshes at the paths this machine sees (a shared filesystem) and do the alignment "
                        "and the Gram products; the same model as without it, to round-off")
    b.add_argument("--workers", type=_positive, default=2, help="with --scheduler local: worker processes (default 2)")
    b.set_defaults(func=cmd_build)

    s = msub.add_parser("show", help="draw the first modes (mean -/+ 3 sd, front and side) and the explained variance")
    s.add_argument("model", help="model file (.npz from `facecorr model build`)")
    s.add_argument("-o", "--output", required=True, help="picture to write (.png)")
    s.add_argument("--modes", type=_positive, default=3, metavar="K", help="how many modes to draw (default 3)")
    s.set_defaults(func=cmd_show)

    e = msub.add_parser("export", help="write the model as a statismo HDF5 file and/or PLY meshes of its modes")
    e.add_argument("model", help="model file (.npz from `facecorr model build`)")
    e.add_argument("--statismo", metavar="OUT.h5", help="statismo / Scalismo HDF5 file (needs facecorr[hdf5])")
    e.add_argument("--ply-modes", metavar="DIR", help="folder for mean.ply and mean -/+ 3 sd of each mode as PLY")
    e.add_argument("--modes", type=_positive, metavar="K", help="with --ply-modes: only the first K modes")
    e.set_defaults(func=cmd_export)

    v = msub.add_parser("eval", help="held-out reconstruction error: leave one scan or subject out",
                        description="For each scan (or subject) under RESULTS, fit a model to all the others and "
                                    "reconstruct the held-out shapes from it: mean vertex error in mm.")
    v.add_argument("results", help="folder of results (the output folder of `facecorr batch`)")
    v.add_argument("--by", choices=["scan", "folder", "prefix"], default="scan",
                   help="what is left out together: one scan, one folder of results (a subject's folder) or the "
                        "scans sharing a file-name prefix before the first '_' (F0002_AN04 -> F0002); default scan")
    v.add_argument("--json", metavar="OUT", help="also write every held-out shape's errors and the summary as JSON")
    _add_fit_options(v)
    v.set_defaults(func=cmd_eval)


def _options(args):
    from ..model import BuildOptions

    return BuildOptions(modes=args.modes, variance=args.variance, scale=args.scale,
                        include_flagged=args.include_flagged)


def _report_reading(skipped, n_failed) -> None:
    if skipped:
        kinds: dict = {}
        for _, flags in skipped:
            for kind in dict.fromkeys(f.split(":", 1)[0] for f in flags):
                kinds[kind] = kinds.get(kind, 0) + 1
        print(f"skipped {len(skipped)} flagged result(s) ("
              + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items()))
              + "; --include-flagged keeps them): " + ", ".join(n for n, _ in skipped[:5])
              + (" ..." if len(skipped) > 5 else ""))
    if n_failed:
        print(f"{n_failed} scan(s) failed registration (failures.json) and have no result")


def cmd_build(args) -> int:
    from ..errors import OutputError
    from ..io.atomic import check_output_paths
    from ..model import fit_model, read_results

    out = Path(args.output)
    if out.suffix.lower() != ".npz":
        raise OutputError(f"{out}: the model is written as .npz")
    check_output_paths([("-o", out)])
    opts = _options(args)
    opts.check()
    if args.scheduler:
        from ..model.distributed import build_model_on_cluster
        from ..model.results import select_results
        from ..pipeline.cluster import connect

        select_results(args.results, neutral=args.neutral, include_flagged=args.include_flagged)  # no cluster
        with connect(args.scheduler, workers=args.workers) as client:  # started for a folder it cannot use
            model, skipped, n_failed = build_model_on_cluster(args.results, client, neutral=args.neutral,
                                                              options=opts)
    else:
        rs = read_results(args.results, neutral=args.neutral, include_flagged=args.include_flagged)
        model = fit_model(rs.shapes, rs.faces, rs.names, source="neutral" if args.neutral else "registered",
                          options=opts)
        skipped, n_failed = rs.skipped, rs.n_failed
    model.save(out)
    _report_reading(skipped, n_failed)
    kept = float(model.explained_variance().sum())
    print(f"{out}: {model.n_scans} scans, {model.n_vertices} vertices, {model.n_modes} modes "
          f"({100 * kept:.1f} % of the variance), {model.alignment} alignment, "
          f"{'expression-removed' if args.neutral else 'registered'} shapes; total variance "
          f"{model.total_variance:.1f} mm^2 ({(model.total_variance / model.n_vertices) ** 0.5:.2f} mm RMS per vertex)")
    return 0


def cmd_show(args) -> int:
    from ..errors import OutputError
    from ..io.atomic import check_output_paths
    from ..model import ShapeModel
    from ..render import plot_shape_modes

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise OutputError(f"{out}: the picture is written as .png")
    check_output_paths([("-o", out)], inputs=[args.model])
    model = ShapeModel.load(args.model)
    kept = float(model.explained_variance().sum())
    what = "expression-removed scans" if model.source == "neutral" else "scans"
    title = (f"{Path(args.model).name}: {model.n_scans} {what}, {model.n_modes} modes ({100 * kept:.1f} % of the "
             f"variance), {model.alignment} alignment; the faces differ from the mean by "
             f"{(model.total_variance / model.n_vertices) ** 0.5:.1f} mm RMS per vertex")
    plot_shape_modes(model.mean, model.components, model.std, model.faces, model.explained_variance(), out,
                     n_modes=args.modes, title=title)
    print(f"{out}: modes 1-{min(args.modes, model.n_modes)} of {model.n_modes}")
    return 0


def cmd_export(args) -> int:
    from ..errors import FacecorrError, OutputError
    from ..model import ShapeModel
    from ..model.export import export_model

    if not args.statismo and not args.ply_modes:
        raise FacecorrError("facecorr model export: give --statismo OUT.h5 and/or --ply-modes DIR")
    if args.modes and not args.ply_modes:
        raise FacecorrError("facecorr model export: --modes only applies to --ply-modes")
    if args.statismo and Path(args.statismo).suffix.lower() not in (".h5", ".hdf5"):
        raise OutputError(f"{args.statismo}: a statismo model is written as .h5")
    model = ShapeModel.load(args.model)
    export_model(model, statismo=args.statismo, ply_dir=args.ply_modes, n_modes=args.modes)
    if args.ply_modes:
        k = model.n_modes if args.modes is None else min(args.modes, model.n_modes)
        print(f"{args.ply_modes}: {1 + 2 * k} PLY meshes (mean, -/+ 3 sd of {k} modes)")
    if args.statismo:
        print(f"{args.statismo}: statismo 0.9 model, {model.n_modes} modes, {model.n_vertices} points")
    return 0


def cmd_eval(args) -> int:
    from ..io.atomic import check_output_paths, write_json
    from ..model import read_results
    from ..model.evaluate import leave_one_out, summarize

    if args.json:
        check_output_paths([("--json", Path(args.json))])
    opts = _options(args)
    opts.check()
    rs = read_results(args.results, neutral=args.neutral, include_flagged=args.include_flagged)
    rows = leave_one_out(rs.shapes, rs.faces, rs.names, by=args.by, options=opts)
    summary = summarize(rows)
    _report_reading(rs.skipped, rs.n_failed)
    by_group: dict = {}
    for r in rows:
        by_group.setdefault(r["group"], []).append(r["mean_error_mm"])
    if args.by != "scan":
        for g, errs in by_group.items():
            print(f"  {g}: {len(errs)} scans, mean error {sum(errs) / len(errs):.3f} mm")
    print(f"leave-one-{args.by}-out over {summary['n_shapes']} shapes ({summary['n_groups']} folds, "
          f"{summary['n_modes_mean']:.1f} modes on average): mean vertex error {summary['mean_error_mm']:.3f} mm "
          f"(median {summary['median_error_mm']:.3f}, worst scan {summary['max_error_mm']:.3f}); the mean shape alone "
          f"{summary['mean_shape_error_mm']:.3f} mm")
    if args.json:
        write_json(args.json, {"by": args.by, "options": {"modes": args.modes, "variance": args.variance,
                                                          "scale": args.scale, "neutral": args.neutral},
                               "summary": summary, "shapes": rows})
    return 0

