"""The ICT face model as the generator's source of heads: identities and expressions.

A subject is ``neutral + sum_k w_k identity[k]`` with ``w_k ~ N(0, s^2)``; ``s =``
:data:`IDENTITY_SIGMA` (1.0, the model's own prior: each mode's stored displacement is one
standard deviation) truncated at :data:`IDENTITY_TRUNCATE` standard deviations so no subject is an
implausible outlier. An expression adds ``sum_j a_j expression[j]`` with ARKit weights in [0, 1]
(recipes in :mod:`facecorr.synth.expressions`). Everything is in millimetres, model frame
(+y up, +z out of the face, the subject's right at -x).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

#: Standard deviation of the identity weights (in units of the model's modes).
IDENTITY_SIGMA = 1.0
#: Identity weights are clipped to +- this many standard deviations.
IDENTITY_TRUNCATE = 2.5


@dataclass(frozen=True)
class ICTModel:
    """The vendored ICT model, arrays converted once for fast blending.

    Attributes
    ----------
    neutral : (N, 3) float64 mm.
    triangles : (M, 3) int64.
    identity : (100, N*3) float32 displacement modes (mm).
    expression : (53, N*3) float32 displacement shapes (mm).
    expression_names : tuple of 53 ARKit names.
    part_id : (N,) int8, part_names : tuple of 7 names.
    landmarks68 : (68,) int64 vertex ids of the iBUG-68 points.
    """

    neutral: np.ndarray
    triangles: np.ndarray
    identity: np.ndarray
    expression: np.ndarray
    expression_names: tuple
    part_id: np.ndarray
    part_names: tuple
    landmarks68: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.neutral)


@lru_cache(maxsize=1)
def load_ict() -> ICTModel:
    """Load the vendored ICT model (cached per process)."""
    path = resources.files("facecorr") / "data" / "ict" / "ict_face_model.npz"
    with resources.as_file(path) as p, np.load(p) as d:
        n = d["neutral"].shape[0]
        return ICTModel(
            neutral=d["neutral"].astype(np.float64),
            triangles=d["triangles"].astype(np.int64),
            identity=d["identity"].astype(np.float32).reshape(-1, n * 3),
            expression=d["expression"].astype(np.float32).reshape(-1, n * 3),
            expression_names=tuple(str(s) for s in d["expression_names"]),
            part_id=d["part_id"].astype(np.int8),
            part_names=tuple(str(s) for s in d["part_names"]),
            landmarks68=d["landmarks68"].astype(np.int64),
        )


def sample_identity(rng: np.random.Generator, n_modes: int = 100) -> np.ndarray:
    """(n_modes,) identity weights ``w_k ~ N(0, IDENTITY_SIGMA^2)``, truncated."""
    w = rng.normal(0.0, IDENTITY_SIGMA, n_modes)
    lim = IDENTITY_TRUNCATE * IDENTITY_SIGMA
    return np.clip(w, -lim, lim)


def _blend(weights: np.ndarray, modes: np.ndarray) -> np.ndarray:
    # einsum without BLAS: a fixed summation order, so results are bitwise identical whatever
    # the BLAS threading of the process (reproducibility across worker counts).
    return np.einsum("k,kn->n", weights.astype(np.float64), modes, optimize=False, dtype=np.float64)


def deform(model: ICTModel, identity_weights: np.ndarray, expression_weights: np.ndarray) -> np.ndarray:
    """(N, 3) float64 vertices (mm, model frame) of a subject showing an expression."""
    d = _blend(identity_weights, model.identity) + _blend(expression_weights, model.expression)
    return model.neutral + d.reshape(-1, 3)
