"""Held-out reconstruction error of a shape model: leave one scan (or one subject) out.

For each group of shapes (one scan, or every scan of one subject), a model is fitted to all the
other shapes with the same settings and each held-out shape is projected onto it
(:meth:`ShapeModel.project`: aligned to the model's mean, reconstructed from the modes, moved
back). Its error is the mean distance (mm) between its vertices and their reconstruction; the
mean shape alone (no modes) is the baseline the modes must beat.
"""

from __future__ import annotations

from pathlib import PurePosixPath

import numpy as np

from ..errors import ShapeModelError
from ..options import resolve
from .build import BuildOptions, fit_model

#: How ``facecorr model eval --by`` groups the results it leaves out together.
GROUPINGS = ("scan", "folder", "prefix")


def group_of(name: str, by: str) -> str:
    """The group of a result name (``F0002/F0002_AN04_F3D``): itself (``scan``), its folder
    (``folder``: ``F0002``) or its file name up to the first underscore (``prefix``: ``F0002``)."""
    p = PurePosixPath(name)
    if by == "scan":
        return name
    if by == "folder":
        return str(p.parent)
    if by == "prefix":
        return p.name.split("_", 1)[0]
    raise ShapeModelError(f"unknown grouping {by!r} (known: {', '.join(GROUPINGS)})")


def leave_one_out(shapes, faces, names, *, by: str = "scan", options=None, progress: bool = True,
                  **overrides) -> list[dict]:
    """Leave-one-group-out reconstruction errors.

    Parameters
    ----------
    shapes : (S, N, 3) mm; faces : (M, 3); names : S result names (grouped by ``by``,
        :func:`group_of`).
    options / ``**overrides`` : BuildOptions of every fold's model.

    Returns
    -------
    One row per shape: ``{"name", "group", "n_modes", "mean_error_mm", "max_error_mm",
    "mean_shape_error_mm", "mahalanobis"}``.
    """
    from tqdm import tqdm

    opts = resolve(options, BuildOptions, overrides, "leave_one_out")
    x = np.asarray(shapes, dtype=np.float64)
    groups = [group_of(n, by) for n in names]
    order = list(dict.fromkeys(groups))
    if len(order) < 2:
        raise ShapeModelError(f"leave-one-out needs at least 2 groups, the results form {len(order)} (by {by})")
    g = np.array(groups)
    rows = []
    for grp in tqdm(order, desc="leave-one-out", unit="fold", disable=not progress, delay=1.0):
        out = g == grp
        if (~out).sum() < 2:
            raise ShapeModelError(f"leaving out {grp!r} leaves {(~out).sum()} shape(s): a model needs 2")
        model = fit_model(x[~out], faces, [n for n, o in zip(names, out) if not o], options=opts)
        for i in np.flatnonzero(out):
            alpha, recon = model.project(x[i])
            _, mean_only = model.project(x[i], n_modes=0)
            err = np.linalg.norm(recon - x[i], axis=1)
            rows.append({"name": names[i], "group": grp, "n_modes": model.n_modes,
                         "mean_error_mm": float(err.mean()), "max_error_mm": float(err.max()),
                         "mean_shape_error_mm": float(np.linalg.norm(mean_only - x[i], axis=1).mean()),
                         "mahalanobis": float(np.sqrt(np.sum(alpha ** 2)))})
    return rows


def summarize(rows) -> dict:
    """Mean / median / max of the per-shape errors of :func:`leave_one_out` (mm)."""
    e = np.array([r["mean_error_mm"] for r in rows])
    m = np.array([r["mean_shape_error_mm"] for r in rows])
    return {"n_shapes": len(rows), "n_groups": len({r["group"] for r in rows}),
            "mean_error_mm": float(e.mean()), "median_error_mm": float(np.median(e)),
            "max_error_mm": float(e.max()), "mean_shape_error_mm": float(m.mean()),
            "n_modes_mean": float(np.mean([r["n_modes"] for r in rows]))}
