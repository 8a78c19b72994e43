"""Principal component analysis of S samples of D numbers, for S much smaller than D.

A face model has S = hundreds of scans and D = 3 x ~5k vertex coordinates. The SVD of the
centred data X = U diag(sigma) W^T (S, D) is found from the small Gram matrix X X^T (S, S): its
eigenvectors are U, its eigenvalues sigma^2, and only the K kept principal directions are
formed, as W_K = X^T U_K / sigma_K. That is S^2 D + S D K operations
instead of a D x D covariance (statismo's PCAModelBuilder does the same). For S > D the thin SVD
of X is used directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Eigenvalues below this share of the largest are numerical noise, not directions: centred data
#: has rank <= S - 1, and the Gram matrix squares the condition number.
RELATIVE_EIGENVALUE_FLOOR = 1e-10


@dataclass
class PCA:
    """The principal components of a data set.

    Attributes
    ----------
    mean : (D,) the sample mean.
    components : (K, D) orthonormal rows, the principal directions, by decreasing variance.
    variances : (K,) sample variances along them (divided by S - 1), descending.
    scores : (S, K) every sample's coordinates along them: ``(x_i - mean) @ components.T``.
    total_variance : float, the sum of all the sample variances (every direction, kept or not).
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    scores: np.ndarray
    total_variance: float


def n_modes_for(variances, total_variance: float, *, modes: int | None = None,
                variance: float | None = None) -> int:
    """How many leading modes to keep: ``modes`` (capped at the number available) or the fewest
    whose variances reach the share ``variance`` (0 < variance <= 1) of ``total_variance``."""
    v = np.asarray(variances, dtype=np.float64)
    if modes is not None:
        return int(min(max(modes, 0), len(v)))
    if variance is None or total_variance <= 0:
        return len(v)
    cum = np.cumsum(v) / total_variance
    # a share of 1.0 means "every mode": round-off must not leave the last one out
    return int(min(len(v), np.searchsorted(cum, variance - 1e-12) + 1))


def principal_components(data, *, modes: int | None = None, variance: float | None = None) -> PCA:
    """PCA of ``data`` (S, D), S >= 2 samples as rows.

    ``modes`` / ``variance``: keep that many modes, or the fewest explaining that share of the
    total variance (:func:`n_modes_for`); neither: every mode with a non-zero variance (at most
    S - 1).
    """
    x = np.asarray(data, dtype=np.float64)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"principal_components: need (S>=2, D) data, got {x.shape}")
    n, d = x.shape
    mean = x.mean(axis=0)
    xc = x - mean
    if n <= d:
        return pca_from_gram(xc @ xc.T, mean, data_norm2=float(np.sum(x * x)), xt_times=lambda v: xc.T @ v,
                             x_times=lambda q: xc @ q, modes=modes, variance=variance)
    _, sig, vt = np.linalg.svd(xc, full_matrices=False)
    w = sig ** 2
    total = float(np.sum(np.clip(w, 0, None))) / (n - 1)
    variances, k = _kept(w, n, total, float(np.sum(x * x)), modes, variance)
    comps, scores = fixed_signs(vt[:k], xc @ vt[:k].T)
    return PCA(mean=mean, components=np.ascontiguousarray(comps), variances=variances[:k].copy(),
               scores=scores, total_variance=total)


#: Seed of the fixed direction that sets each mode's sign (:func:`fixed_signs`).
SIGN_SEED = 20261202


def fixed_signs(components, scores):
    """(components, scores) with each mode's sign chosen so that its dot product with a fixed
    pseudo-random direction is positive (column k of ``scores`` flipped with row k of
    ``components``).

    An eigenvector's sign is arbitrary: two computations of one PCA that round differently (one
    BLAS or another, the Gram matrix summed in one piece or by blocks on a Dask cluster) may
    return a mode and its opposite. A random direction, unlike "the largest coordinate
    positive", is not fooled by a left-right symmetric mode (mirrored vertices' x displacements
    tie in size with opposite signs)."""
    c = np.asarray(components, dtype=np.float64)
    if not len(c):
        return c, scores
    direction = np.random.default_rng(SIGN_SEED).standard_normal(c.shape[1])
    flip = np.where(c @ direction < 0, -1.0, 1.0)
    return c * flip[:, None], np.asarray(scores) * flip[None, :]


def _kept(w, n: int, total: float, data_norm2: float, modes, variance):
    """(variances of the modes with a non-zero variance, how many to keep) from the eigenvalues
    ``w`` (descending) of S = ``n`` samples."""
    floor = RELATIVE_EIGENVALUE_FLOOR * max(float(w[0]), 0.0)
    # no variation at all (identical shapes): round-off of the data's own size
    none = float(w[0]) <= 1e-20 * data_norm2
    rank = 0 if none else int(min(np.sum(w > floor), n - 1))
    variances = w[:rank] / (n - 1)
    return variances, n_modes_for(variances, total, modes=modes, variance=variance)


def pca_from_gram(gram, mean, *, data_norm2: float, xt_times, x_times, modes: int | None = None,
                  variance: float | None = None) -> PCA:
    """PCA of S centred samples X (S, D), S <= D, given their Gram matrix and two products with X.

    The data itself need not be here: on a Dask cluster the rows of X stay in the workers, which
    compute the Gram matrix by blocks and the two products by chunks of rows
    (:mod:`facecorr.model.distributed`); :func:`principal_components` passes its own array.

    Parameters
    ----------
    gram : (S, S) X X^T; mean : (D,) the samples' mean (stored in the PCA).
    data_norm2 : the sum of the squared uncentred data (tells "no variation" from round-off).
    xt_times : callable (S, K) V -> (D, K) X^T V; x_times : callable (D, K) Q -> (S, K) X Q.
    modes, variance : as in :func:`principal_components`.
    """
    g = np.asarray(gram, dtype=np.float64)
    n = len(g)
    w, v = np.linalg.eigh(g)
    order = np.argsort(w)[::-1]
    w, v = w[order], v[:, order]
    total = float(np.sum(np.clip(w, 0, None))) / (n - 1)
    variances, k = _kept(w, n, total, data_norm2, modes, variance)
    d = len(mean)
    if not k:
        return PCA(mean=mean, components=np.zeros((0, d)), variances=variances[:0].copy(), scores=np.zeros((n, 0)),
                   total_variance=total)
    approx = xt_times(v[:, :k]) / np.sqrt(w[:k])  # X^T u_k / sigma_k: unit vectors along the data
    # The Gram matrix squares the condition number: small modes come out a little off
    # orthogonal (~eps * w_0 / w_k). Orthonormalise (Householder QR keeps the leading
    # directions) and re-solve within that span (Rayleigh-Ritz: a K-column SVD of X Q).
    q, _ = np.linalg.qr(approx)
    u2, sig2, wt2 = np.linalg.svd(x_times(q), full_matrices=False)
    comps, scores = fixed_signs(wt2 @ q.T, u2 * sig2)
    return PCA(mean=mean, components=np.ascontiguousarray(comps), variances=(sig2 ** 2 / (n - 1))[:k].copy(),
               scores=scores, total_variance=total)
