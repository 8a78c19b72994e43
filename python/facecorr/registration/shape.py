"""Shape fitting (paper §4.3): per-vertex 3x4 transforms, data + smooth + rigid energies, L-BFGS.

The optimisation runs in Rust (``facecorr._core.shape_fit``, see ``rust/src/shape_fit.rs`` for the
outer/inner loop and every choice the paper leaves open); this module validates the inputs and
wraps the result.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import _core
from ..geometry.mesh import Mesh
from ..options import resolve

#: The defaults: the paper's weights (ω_data 1, ω_smooth 20000, ω_rigid 10, ≤ 1000 L-BFGS
#: iterations per solve) with fewer weight levels relaxed faster (8 levels × 0.38: ω_smooth down to
#: 23, near where the paper's 12 halvings end, 10), L-BFGS memory 5 and
#: relative-change tolerances 1e-3 for an inner solve and 1e-2 for "negligible" (when to relax):
#: about the same error for less CPU (BENCHMARKS.md, "Where the defaults come from").
#: ``rel_tol=1e-4, n_levels=12, relax_factor=0.5, memory=10, relax_tol=1e-3, max_distance=inf`` is the paper-literal
#: run.
@dataclass(frozen=True)
class ShapeFitOptions:
    """Settings of :func:`fit_shape` (the paper's weights and halving schedule; lengths in mm,
    angles in degrees). The Rust binding receives every field; it has no defaults of its own."""

    w_data: float = 1.0             # ω_data
    w_smooth: float = 20000.0       # ω_smooth at the first level
    w_rigid: float = 10.0           # ω_rigid at the first level
    # Both multiplied by this from one level to the next (the paper halves them, over 12 levels).
    # 0.38 over 8 levels ends about as soft as the paper's 12 halvings, in 8 levels' time: the
    # nose and eyes follow faces unlike the template better (out of model, true landmarks: nose
    # 0.88 -> 0.79 mm) at no cost in model (BENCHMARKS.md, "Out of model, fourth pass").
    relax_factor: float = 0.38
    n_levels: int = 8               # weight levels (the paper: 12)
    # Closest-point updates per level (each followed by an L-BFGS solve). 2 since issue 17: the
    # third to fifth solves of a level took ~2 iterations each (re-found matches barely move
    # the optimum); 5 -> 2 cut the fit's time by ~25 % with region means within 0.4 % in and
    # out of model (BENCHMARKS.md, "Throughput, sixth pass").
    max_icp: int = 2
    relax_tol: float = 1e-2         # relative energy change below which a level ends ("negligible")
    max_iter: int = 1000            # L-BFGS iterations per solve
    rel_tol: float = 1e-3           # relative change that ends a solve (the paper: 1e-4)
    memory: int = 5                 # L-BFGS correction pairs (the paper: 10)
    normal_angle_deg: float = 80.0  # a match whose normals differ more is invalid
    # Matches farther than this (mm) are dropped (the paper: none, inf). The template's nostril
    # rims have no counterpart on a scan (nostrils are holes), and without a cap they were pulled
    # onto the skin around, bending the nose; some of them flipped between two surfaces every ICP
    # update (hundreds of wasted L-BFGS iterations). The MHD rises a little: those vertices stay
    # where the smoothness puts them, inside the holes, instead of on the nearest skin.
    max_distance: float = 5.0
    reject_boundary: bool = True    # scan boundary vertices are never matches (hair, ears, holes' rims)
    # Matches are the closest points on the scan's surface (among the triangles around the
    # ``surface_k`` nearest vertices; 0 = the nearest vertex, the paper), and the three tests
    # above are ramps, not steps (± ``angle_band_deg`` about the angle, ``distance_band`` mm below
    # the cap, × (1 − boundary share)): the fit is then continuous in its input (issue 13, #15).
    # 1 since issue 17: the triangles around the nearest vertex give the same fit as 3 (region means
    # within 0.5 %, BENCHMARKS.md "Throughput, third pass") at half the query time.
    surface_k: int = 1
    angle_band_deg: float = 10.0
    distance_band: float = 1.0
    w_landmark: float = 0.0         # ω of the landmark term (the paper: none)
    precondition: bool = True       # diagonal preconditioner of the L-BFGS
    # Normal-aware soft matches (rust/src/soft_match.rs; 0 = off): each match also pulls the
    # vertex along the surface, w β ‖P (s − p̃)‖² with β = ``w_tangential``, towards the scan
    # vertices within ``feature_radius`` mm whose normals match the template's (λ =
    # ``feature_lambda`` mm per unit normal difference, temperature ``feature_tau`` mm).
    feature_lambda: float = 0.0
    feature_tau: float = 2.0
    feature_radius: float = 7.0
    w_tangential: float = 0.5


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


def fit_shape(vertices, faces, scan: Mesh, anchors=None, template_weight=None,
              options: ShapeFitOptions | None = None, **overrides) -> ShapeFit:
    """Deform a template onto a scan with per-vertex affine transforms (paper §4.3).

    Parameters
    ----------
    vertices : (N, 3) float, the template to deform (e.g. the fitted expression P(alpha)), mm,
        already aligned with the scan.
    faces : (M, 3) int, the template's triangles (its edges define E_smooth).
    scan : Mesh, the target (mm); its cached vertex normals and boundary flags are used.
    anchors : optional (ids (L,), points (L, 3)): template vertex ids pulled to scan positions by
        the landmark term (weight ``w_landmark``; 0 by default = the paper).
    template_weight : optional (N,) multiplier of the data weight per template vertex (e.g. 0 on
        the inner lip rim).
    options : ShapeFitOptions (default ``ShapeFitOptions()``); ``**overrides`` change its fields.

    Returns
    -------
    ShapeFit
    """
    opts = resolve(options, ShapeFitOptions, overrides, "fit_shape")
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if anchors is None:
        ids, pts = np.zeros(0, np.int64), np.zeros((0, 3))
    else:
        ids = np.ascontiguousarray(anchors[0], dtype=np.int64).reshape(-1)
        pts = np.ascontiguousarray(anchors[1], dtype=np.float64).reshape(-1, 3)
    tw = None if template_weight is None else np.ascontiguousarray(template_weight, dtype=np.float64)
    t0 = time.perf_counter()
    out_v, out_t, solves = _core.shape_fit(
        v, f, scan.surface, ids, pts, template_weight=tw, **asdict(opts))
    return ShapeFit(vertices=out_v, transforms=out_t, solves=list(solves), seconds=time.perf_counter() - t0)
