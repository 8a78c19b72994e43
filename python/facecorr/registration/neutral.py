"""The expression-removed shape of a registration (issue 15): same identity, neutral face.

Why a second, linear fit instead of the registration's own blendshape weights: the registration's
identity basis was learned with the expression left in (:mod:`.identity`), so its modes carry much
of a subject's expression, and removing only the fitted blendshape displacement Σ α_k A_k leaves
most of it (measured: the neutral shapes of 6 subjects' expressive scans came only 0-0.6 mm
closer to their neutral scan's registration). Here the registered template X (template vertex
order, so the fit needs no correspondence search) is decomposed with an identity basis learned
from *neutral* scans only (``facecorr train-identity DB --neutral-only``; packaged:
``data/identity_neutral.npz``) beside the 14 blendshapes:

    min_{s,R,t,α,γ,β}  ‖ s R X + t − (A0 + m + B_id β + B_ex α + B_res γ) ‖² + μ ‖β‖² + ν ‖γ‖²,   α ∈ [0, 1]

solved jointly in the similarity and (α, γ, β) by Gauss-Newton steps, each a box QP
(:func:`.expression.box_qp`). B_res are the modes of what the 14 blendshapes miss of real
expressions (a disgust's nose wrinkle and raised upper lip), learned from the training subjects'
expressive minus neutral shapes (``facecorr train-identity DB --expression-residual``; packaged:
``data/expression_residual.npz``, 10 modes). The neutral shape is X − (s R)⁻¹ (B_ex α + B_res γ):
only the expression part is taken away, so every detail the fit did not explain (the shape
fit's per-vertex identity detail, the residual) stays in, in the scan's frame. The priors μ and
ν (mm², per mode of one standard deviation) keep the identity modes from taking up expression
and the residual modes from taking up identity: BENCHMARKS.md ("The expression-removed shape")
has the measured curves.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ..geometry.transforms import kabsch, rotation_from_vector
from .expression import box_qp
from .identity import IdentityBasis, load_identity_basis

#: Identity basis of the neutral scans only (training split of the synthetic bu3dfe database,
#: seed 0, 50 subjects, 40 modes: ``facecorr train-identity DB --neutral-only``).
NEUTRAL_BASIS_PATH = Path(__file__).resolve().parent.parent / "data" / "identity_neutral.npz"
#: What the blendshapes miss of the expressions (training split of the same database, 50
#: subjects x 6 expressions at level 4, 10 modes: ``facecorr train-identity DB
#: --expression-residual --modes 10``).
RESIDUAL_BASIS_PATH = Path(__file__).resolve().parent.parent / "data" / "expression_residual.npz"


@dataclass(frozen=True)
class NeutralOptions:
    """Settings of :func:`neutral_shape`."""

    identity_prior: float = 1e3  # μ, mm² per mode (1 σ): the plateau of the measured curve
    rounds: int = 10             # Gauss-Newton steps at most (a model face: settled after ~4)
    # ν, mm² per residual expression mode (1 σ), and how many of the packaged residual modes are
    # used (0: the blendshapes alone). Chosen on 10 training subjects held out of both bases
    # (BENCHMARKS.md): 300 is inside the plateau 100-1000, 10 modes inside 5-40.
    residual_prior: float = 300.0
    residual_modes: int = 10


_NORMAL_CACHE: dict = {}


def _normal_matrix(blend: np.ndarray, resid, n_res: int, ident: np.ndarray):
    """(J (3N, K+R+M), JᵀJ) of the blendshapes, the first ``n_res`` residual expression modes of
    ``resid`` (a basis's modes array, or None) and the identity modes, built once per template,
    bases and ``n_res`` (a batch worker decomposes every scan with the same ones)."""
    key = (id(blend), id(resid), n_res, id(ident))
    hit = _NORMAL_CACHE.get(key)
    if hit is None:
        n3 = np.asarray(blend).shape[1] * 3
        parts = [blend] + ([np.asarray(resid)[:n_res]] if n_res else []) + [ident]
        j = np.concatenate([np.asarray(a, np.float64).reshape(len(a), n3) for a in parts]).T
        if len(_NORMAL_CACHE) >= 4:
            _NORMAL_CACHE.clear()
        hit = _NORMAL_CACHE[key] = (blend, resid, ident, j, j.T @ j)  # the arrays kept: their ids stay theirs
    return hit[3], hit[4]


@functools.lru_cache(maxsize=1)
def packaged_neutral_basis() -> IdentityBasis:
    return load_identity_basis(NEUTRAL_BASIS_PATH)


@functools.lru_cache(maxsize=1)
def packaged_residual_basis() -> IdentityBasis:
    """The packaged residual expression modes (:data:`RESIDUAL_BASIS_PATH`)."""
    return load_identity_basis(RESIDUAL_BASIS_PATH)


def neutral_shape(vertices, template, basis: IdentityBasis | None = None,
                  options: NeutralOptions | None = None,
                  residual: IdentityBasis | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Remove the expression from a registered template.

    Parameters
    ----------
    vertices : (N, 3) the registered template (template vertex order), mm, any frame.
    template : facecorr.template.Template (its rest shape A0 and blendshapes B_ex).
    basis : identity basis without expression (default: the packaged neutral one).
    options : NeutralOptions.
    residual : the residual expression modes (default: the packaged ones; their first
        ``options.residual_modes`` are used).

    Returns
    -------
    neutral : (N, 3) mm, the same frame as ``vertices``.
    alpha : (K,) the blendshape weights taken away (template.blendshape_names order; the residual
        modes' part is taken away too, not reported).
    """
    # Single-threaded BLAS: the products are small, and the answer must not depend on how many
    # threads a worker's BLAS happens to have (a Dask worker's and a local batch's files agree).
    with threadpool_limits(limits=1, user_api="blas"):
        return _neutral_shape(vertices, template, basis, options, residual)


def _neutral_shape(vertices, template, basis, options, residual):
    o = options or NeutralOptions()
    basis = basis or packaged_neutral_basis()
    n_res = max(0, int(o.residual_modes))
    if residual is None and n_res:
        residual = packaged_residual_basis()
    res_modes = np.asarray(residual.modes)[:n_res] if n_res else np.zeros((0,) + np.asarray(template.vertices).shape)
    v = np.asarray(vertices, dtype=np.float64)
    a0 = np.asarray(template.vertices, dtype=np.float64)
    if v.shape != a0.shape:
        raise ValueError(f"vertices must be the template's {a0.shape}, got {v.shape}")
    blend, ident = template.blendshapes, basis.modes
    if res_modes.shape[1:] != a0.shape:
        raise ValueError(f"residual expression modes must be on the template's {a0.shape}, got {res_modes.shape[1:]}")
    k, m = len(blend) + len(res_modes), len(ident)  # the expression part: blendshapes, then residual modes
    j, h0 = _normal_matrix(blend, residual.modes if n_res else None, n_res, ident)
    base = a0 + np.asarray(basis.mean, dtype=np.float64)
    # Gauss-Newton on (α, β) and a small similarity (σ scale, ω rotation about the centroid,
    # τ translation) of the input, from a Procrustes start on the mean face: the two are solved
    # together because expression moves the whole-face Procrustes pose (an open jaw tilts it), so
    # alternating them converges slowly (measured: 20 alternations still left 4 mm on a model face).
    r, s, t = kabsch(v, base, with_scale=True)
    x_pose = s * v @ r.T + t  # the input in the template's frame, updated by every step
    lin = s * r               # x_pose = lin @ v + shift
    nb = len(blend)
    mu = np.r_[np.zeros(nb), np.full(len(res_modes), float(o.residual_prior)), np.full(m, float(o.identity_prior)),
               np.zeros(7)]
    lo = np.r_[np.zeros(nb), np.full(len(res_modes) + m + 7, -np.inf)]
    hi = np.r_[np.ones(nb), np.full(len(res_modes) + m + 7, np.inf)]
    z = np.zeros(k + m + 7)
    for _ in range(max(1, int(o.rounds))):
        c = x_pose.mean(axis=0)
        q = x_pose - c
        px, py, pz = q.T
        zero = np.zeros_like(px)
        # columns of the pose unknowns: d x_pose / d(σ, ωx, ωy, ωz, τx, τy, τz), each (3N,)
        cols = np.stack([q.ravel(),
                         np.stack([zero, -pz, py], 1).ravel(), np.stack([pz, zero, -px], 1).ravel(),
                         np.stack([-py, px, zero], 1).ravel(),
                         *(np.tile(np.eye(3)[a], len(q)) for a in range(3))], axis=1)
        cross = -j.T @ cols
        h = np.block([[h0, cross], [cross.T, cols.T @ cols]]) + np.diag(mu)
        resid = (x_pose - base).ravel()
        g = np.r_[j.T @ resid, -cols.T @ resid]
        z[k + m:] = 0.0  # the pose part is a step from the current pose
        z = box_qp(h, g, z, lo, hi)
        sig, om, tau = z[k + m], z[k + m + 1:k + m + 4], z[k + m + 4:]
        step = (1.0 + sig) * rotation_from_vector(om)
        x_pose = q @ step.T + c + tau
        lin = step @ lin
        if abs(sig) < 1e-9 and np.abs(om).max() < 1e-9 and np.abs(tau).max() < 1e-6:
            break
    x = z[:k + m]
    expression = np.tensordot(x[:nb], np.asarray(blend, np.float64), axes=1)  # (N, 3) in the template's frame
    if len(res_modes):
        expression = expression + np.tensordot(x[nb:k], np.asarray(res_modes, np.float64), axes=1)
    return v - expression @ np.linalg.inv(lin).T, x[:nb]
