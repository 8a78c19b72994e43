"""Vertex classification by FP descriptors (paper §3.4, "FPPCA").

Training: the FP vectors (S radii) of the training landmarks are projected by PCA to D = 3
dimensions. For each class (landmark) i, the medoid m_i of its projected samples is the sample with
the smallest summed Euclidean distance to the others; the spread is
``sigma_i = sqrt(mean_k ||p_k - m_i||^2)`` (the root-mean-square distance to the medoid, i.e. the
standard deviation measured from the medoid; the paper does not define it further). The
**M-cluster** keeps the samples with ``||p_k - m_i|| <= M sigma_i`` (M = 1.5), and the decision rule
E_i is the minimum-volume enclosing ellipsoid of the M-cluster (Khachiyan, :mod:`.mvee`).

Prediction: a descriptor gets label i when its projection lies inside E_i; several labels (the
left/right symmetric classes overlap) or none are possible.

PCA is on the raw FP values (all radii share one unit: area ratio), centred, not whitened, as in
the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mvee import mvee


@dataclass
class Classifier:
    """mean (S,), components (D, S) PCA; medoids (L, D); sigma (L,); ellipse_centers (L, D);
    ellipse_A (L, D, D) decision ellipsoids in PCA space."""

    mean: np.ndarray
    components: np.ndarray
    medoids: np.ndarray
    sigma: np.ndarray
    ellipse_centers: np.ndarray
    ellipse_A: np.ndarray

    @property
    def n_classes(self) -> int:
        return len(self.medoids)

    def project(self, fp: np.ndarray) -> np.ndarray:
        """(n, D) PCA coordinates of FP vectors fp (n, S)."""
        fp = np.atleast_2d(np.asarray(fp, dtype=np.float64))
        if fp.shape[1] != len(self.mean):
            raise ValueError(f"classifier: FP vectors must have {len(self.mean)} radii, got {fp.shape[1]}")
        return (fp - self.mean) @ self.components.T

    def ellipsoid_value(self, fp: np.ndarray) -> np.ndarray:
        """(n, L) values (p - C_i)^T A_i (p - C_i); <= 1 means inside E_i."""
        p = self.project(fp)
        y = p[:, None, :] - self.ellipse_centers[None]
        return np.einsum("nli,lij,nlj->nl", y, self.ellipse_A, y)

    def label(self, fp: np.ndarray) -> np.ndarray:
        """(n, L) bool: descriptor n satisfies rule E_i."""
        return self.ellipsoid_value(fp) <= 1.0 + 1e-9  # round-off on the boundary

    def medoid_distance(self, fp: np.ndarray) -> np.ndarray:
        """(n, L) Euclidean distances in PCA space to each class medoid."""
        p = self.project(fp)
        return np.linalg.norm(p[:, None, :] - self.medoids[None], axis=-1)


def medoid(points: np.ndarray) -> int:
    """Index of the point with the smallest summed Euclidean distance to all others."""
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    return int(np.argmin(d.sum(axis=1)))


def fit_classifier(fp: np.ndarray, labels: np.ndarray, n_classes: int, dim: int = 3, m: float = 1.5,
                   min_thickness: float = 1e-3) -> Classifier:
    """Train the FPPCA classifier.

    Parameters
    ----------
    fp : (n, S) FP vectors of training landmarks.
    labels : (n,) class index in [0, n_classes) of each vector.
    dim : PCA dimension D (paper: 3).
    m : M-cluster radius in standard deviations (paper: 1.5).
    min_thickness : if an M-cluster is degenerate (fewer than D + 1 points or flat), its
        ellipsoid is thickened to this semi-axis in PCA units (see mvee's ``regularization``).
    """
    fp = np.asarray(fp, dtype=np.float64)
    labels = np.asarray(labels)
    if fp.ndim != 2 or len(fp) != len(labels):
        raise ValueError(f"fit_classifier: fp (n, S) and labels (n,) disagree: {fp.shape}, {labels.shape}")
    if not np.isfinite(fp).all():
        raise ValueError("fit_classifier: FP vectors contain NaN or inf")
    mean = fp.mean(axis=0)
    _, _, vt = np.linalg.svd(fp - mean, full_matrices=False)
    comps = vt[:dim]
    # Fix the sign of each component (largest |loading| positive) so models are reproducible.
    comps *= np.sign(comps[np.arange(len(comps)), np.argmax(np.abs(comps), axis=1)])[:, None]
    proj = (fp - mean) @ comps.T
    meds, sig, cen, amat = [], [], [], []
    for c in range(n_classes):
        p = proj[labels == c]
        if len(p) == 0:
            raise ValueError(f"fit_classifier: class {c} has no training samples")
        mk = p[medoid(p)]
        dist = np.linalg.norm(p - mk, axis=1)
        s = float(np.sqrt(np.mean(dist**2)))
        keep = p[dist <= m * s] if s > 0 else p
        e = mvee(keep, regularization=None) if _full_rank(keep, dim) else mvee(keep, regularization=min_thickness)
        meds.append(mk)
        sig.append(s)
        cen.append(e.center)
        amat.append(e.A)
    return Classifier(mean=mean, components=comps, medoids=np.array(meds), sigma=np.array(sig),
                      ellipse_centers=np.array(cen), ellipse_A=np.array(amat))


def _full_rank(p: np.ndarray, dim: int) -> bool:
    if len(p) < dim + 1:
        return False
    s = np.linalg.svd(p - p.mean(0), compute_uv=False)
    return bool(s[-1] > 1e-9 * max(s[0], 1e-300))
