"""CLI: ``facecorr train`` (the landmark model) and ``facecorr train-identity`` (the identity basis)."""

from __future__ import annotations

from pathlib import Path


def add_commands(sub) -> None:
    t = sub.add_parser("train", help="train the landmark model on a synthetic database",
                       description="Train the landmark model (FP node potentials, canonical-form edge "
                                   "potentials, FPPCA ellipsoids) on the database's training split.")
    t.add_argument("db", help="synthetic database folder (with index.json)")
    t.add_argument("--out", required=True, help="model file to write (.npz)")
    t.add_argument("--neutral-only", action="store_true", help="train on neutral scans only (Tn); default all (Te)")
    t.add_argument("--workers", type=int, default=2)
    t.set_defaults(func=cmd_train)

    ti = sub.add_parser("train-identity", help="learn the identity basis fitted with the expression",
                        description="PCA of the template's shape on every training scan of a synthetic "
                                    "database (from its dense ground truth); see facecorr.registration.identity.")
    ti.add_argument("db", help="synthetic database folder (with index.json and *_dense.npz)")
    ti.add_argument("--out", required=True, help="basis file to write (.npz)")
    ti.add_argument("--modes", type=int, default=40, help="modes kept (default 40)")
    ti.add_argument("--neutral-only", action="store_true", help="learn from the neutral scans only")
    ti.add_argument("--expression-residual", action="store_true",
                    help="learn instead what the blendshapes miss of the expressions (each training subject's "
                         "expressive minus neutral shape, its blendshape fit removed), for the expression-removed "
                         "shape (packaged: data/expression_residual.npz, --modes 10)")
    ti.set_defaults(func=cmd_train_identity)


def cmd_train(args) -> int:
    from ..landmarks.train import train

    model = train(args.db, args.out, neutral_only=args.neutral_only, workers=args.workers)
    print(f"wrote {args.out} ({model.params['n_scans']} scans, {model.params['n_failed']} failed)")
    return 0


def cmd_train_identity(args) -> int:
    from ..errors import FacecorrError
    from ..registration.identity_training import train_identity_basis

    if not (Path(args.db) / "index.json").is_file():
        raise FacecorrError(f"{args.db}: not a synthetic database (no index.json)")
    if args.expression_residual and args.neutral_only:
        raise FacecorrError("--expression-residual learns from the expressive scans: drop --neutral-only")
    try:
        if args.expression_residual:
            from ..registration.identity_training import train_expression_residual

            basis = train_expression_residual(args.db, n_modes=args.modes)
        else:
            basis = train_identity_basis(args.db, n_modes=args.modes, neutral_only=args.neutral_only)
    except ValueError as e:
        raise FacecorrError(str(e)) from None
    basis.save(args.out)
    print(f"wrote {args.out} ({basis.n_modes} modes from {basis.n_samples} scans, "
          f"{100 * basis.explained.sum():.1f} % of the variance)")
    return 0
