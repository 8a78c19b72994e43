"""Gaussian maximum-likelihood fits and log-densities (node and edge potentials, paper §3.1)."""

from __future__ import annotations

import numpy as np


def fit_gaussian(samples: np.ndarray, ridge: float = 1e-4, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """ML mean (k,) and covariance (k, k) of samples (n, k), regularised.

    ``ridge`` adds ``ridge * trace(C) / k`` to the diagonal (a relative Tikhonov term so a
    covariance from few samples stays invertible); ``floor`` is an absolute variance floor
    (e.g. mm^2 for positions, so a landmark that never moved in training is not over-trusted).
    """
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"fit_gaussian: need at least 2 samples of shape (n, k), got {x.shape}")
    mu = x.mean(axis=0)
    c = (x - mu).T @ (x - mu) / len(x)  # maximum likelihood (1/n)
    k = c.shape[0]
    c = c + (ridge * max(np.trace(c) / k, 1e-300) + floor) * np.eye(k)
    return mu, 0.5 * (c + c.T)


def log_density(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Gaussian log-density of rows of x (..., k)."""
    x = np.asarray(x, dtype=np.float64)
    k = len(mean)
    chol = np.linalg.cholesky(cov)
    y = (x - mean).reshape(-1, k)
    z = np.linalg.solve(chol, y.T)
    maha = np.sum(z * z, axis=0)
    logdet = 2.0 * np.sum(np.log(np.diag(chol)))
    return (-0.5 * (maha + logdet + k * np.log(2 * np.pi))).reshape(x.shape[:-1])


def mahalanobis2(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distances of rows of x (..., k)."""
    x = np.asarray(x, dtype=np.float64)
    k = len(mean)
    chol = np.linalg.cholesky(cov)
    z = np.linalg.solve(chol, (x - mean).reshape(-1, k).T)
    return np.sum(z * z, axis=0).reshape(x.shape[:-1])
