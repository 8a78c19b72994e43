"""Shape fitting (paper §4.3): per-vertex 3x4 transforms, data + smooth + rigid energies, L-BFGS.

The optimisation runs in Rust (``facecorr._core.shape_fit``, see ``rust/src/shape_fit.rs`` for the
outer/inner loop and every choice the paper leaves open); this module validates the inputs and
wraps the result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .. import _core
from ..mesh import Mesh

#: Defaults: the paper's weights (ω_data 1, ω_smooth 20000, ω_rigid 10, halving, ≤ 1000 L-BFGS
#: iterations per solve). Measured on synthetic test scans (BENCHMARKS.md, "Registration
#: (issue 5)"): 8 weight levels (ω_smooth down to 156; 6 / 8 / 10 levels: dense error 1.92 /
#: 1.83 / 1.82 mm, shape CPU 0.47 / 0.73 / 0.83 s on 14 scans), L-BFGS memory 5 (same error as
#: 10, -20 % CPU), relative-change tolerances 1e-3 for an inner solve (the paper's 1e-4 costs
#: twice the evaluations for 0.004 mm) and 1e-2 for "negligible" (when to relax).
#: ``rel_tol=1e-4, n_levels=12, memory=10, relax_tol=1e-3, max_distance=inf`` is the paper-literal
#: run.
SHAPE_DEFAULTS = dict(
    w_data=1.0,
    w_smooth=20000.0,
    w_rigid=10.0,
    relax_factor=0.5,
    n_levels=8,
    max_icp=5,
    relax_tol=1e-2,
    max_iter=1000,
    rel_tol=1e-3,
    memory=5,
    normal_angle_deg=80.0,
    # Matches farther than this (mm) are dropped (the paper: none, inf). The template's nostril
    # rims have no counterpart on a scan (nostrils are holes), and without a cap they were pulled
    # onto the skin around, bending the nose; some of them flipped between two surfaces every ICP
    # update (hundreds of wasted L-BFGS iterations). 70 bu3dfe test scans, predicted landmarks,
    # inf / 10 / 7 / 5 / 3 mm: nose 0.94 / 0.73 / 0.67 / 0.67 / 0.67 mm, dense 1.457 / 1.448 /
    # 1.452 / 1.453 / 1.451, eyebrows 1.48 / 1.50 / 1.51 / 1.51 / 1.51, shape 0.32 / 0.28 / 0.21 /
    # 0.20 / 0.20 s (2 processes). The MHD rises (0.97 -> 1.07 mm at 5): those vertices now stay
    # where the smoothness puts them, inside the holes, instead of on the nearest skin.
    max_distance=5.0,
    reject_boundary=True,
    w_landmark=0.0,
    template_weight=None,
    precondition=True,
)


@dataclass
class ShapeFit:
    """Result of :func:`fit_shape`.

    Attributes
    ----------
    vertices : (N, 3) float64, the deformed template, mm, the input frame.
    transforms : (N, 3, 4) float64, T_i with vertices[i] = T_i @ [p_i, 1].
    solves : list of dict, one per inner L-BFGS solve (level, weights, energy terms, number of
        valid matches, iterations, evaluations).
    seconds : float, wall time.
    """

    vertices: np.ndarray
    transforms: np.ndarray
    solves: list = field(default_factory=list)
    seconds: float = 0.0


def fit_shape(vertices, faces, scan: Mesh, anchors=None, scan_normals=None, scan_boundary=None,
              **options) -> ShapeFit:
    """Deform a template onto a scan with per-vertex affine transforms (paper §4.3).

    Parameters
    ----------
    vertices : (N, 3) float, the template to deform (e.g. the fitted expression P(alpha)), mm,
        already aligned with the scan.
    faces : (M, 3) int, the template's triangles (its edges define E_smooth).
    scan : Mesh, the target (mm); its vertex normals and boundary vertices are used.
    anchors : optional (ids (L,), points (L, 3)): template vertex ids pulled to scan positions by
        the landmark term (weight ``w_landmark``; 0 by default = the paper).
    scan_normals, scan_boundary : optional precomputed (S, 3) unit normals and (S,) bool boundary
        flags of the scan (computed if None).
    **options : any of :data:`SHAPE_DEFAULTS` (weights, schedule, normal angle in degrees,
        ``max_distance`` in mm, ``reject_boundary``, ``template_weight`` (N,) multiplier of the
        data weight per template vertex, e.g. 0 on the inner lip rim).

    Returns
    -------
    ShapeFit
    """
    unknown = set(options) - set(SHAPE_DEFAULTS)
    if unknown:
        raise TypeError(f"fit_shape: unknown option(s) {', '.join(sorted(unknown))}")
    opts = {**SHAPE_DEFAULTS, **options}
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if anchors is None:
        ids, pts = np.zeros(0, np.int64), np.zeros((0, 3))
    else:
        ids = np.ascontiguousarray(anchors[0], dtype=np.int64).reshape(-1)
        pts = np.ascontiguousarray(anchors[1], dtype=np.float64).reshape(-1, 3)
    t0 = time.perf_counter()
    sn = scan.vertex_normals if scan_normals is None else scan_normals
    sb = scan.is_boundary if scan_boundary is None else scan_boundary
    out_v, out_t, solves = _core.shape_fit(
        v, f, scan.vertices, np.ascontiguousarray(sn, dtype=np.float64), np.ascontiguousarray(sb, dtype=bool),
        ids, pts,
        w_data=float(opts["w_data"]), w_smooth=float(opts["w_smooth"]), w_rigid=float(opts["w_rigid"]),
        relax_factor=float(opts["relax_factor"]), n_levels=int(opts["n_levels"]), max_icp=int(opts["max_icp"]),
        relax_tol=float(opts["relax_tol"]), max_iter=int(opts["max_iter"]), rel_tol=float(opts["rel_tol"]),
        memory=int(opts["memory"]), normal_angle_deg=float(opts["normal_angle_deg"]),
        max_distance=float(opts["max_distance"]), reject_boundary=bool(opts["reject_boundary"]),
        w_landmark=float(opts["w_landmark"]),
        precondition=bool(opts["precondition"]),
        template_weight=None if opts["template_weight"] is None else np.ascontiguousarray(opts["template_weight"], dtype=np.float64),
    )
    return ShapeFit(vertices=out_v, transforms=out_t, solves=list(solves), seconds=time.perf_counter() - t0)
