"""The statistical shape model: a mean face, orthonormal modes and their variances, in mm.

A shape is ``mean + sum_k alpha_k * sqrt(variances[k]) * components[k]``: the coefficients alpha
are in standard deviations (alpha ~ N(0, 1) for the population the model was built from), the
convention of statismo's ``DrawSample`` / ``ComputeCoefficients``.

The file (``facecorr model build -o model.npz``) is an uncompressed npz holding

    mean        (N, 3) float64, mm, in the template's frame (+y up, +z out of the face)
    components  (K, N, 3) float64, orthonormal (flattened to K rows of 3N)
    variances   (K,) float64, mm^2, descending
    n_scans     ()  int, the number of shapes the model was built from
    faces       (M, 3) int64, the template's triangles
    names       (n_scans,) str, the results the shapes came from (paths under the results folder)
    scores      (n_scans, K) float64, their coefficients (standard deviations)
    alignment   () str, "rigid" or "similarity" (how the shapes were aligned, and how
                :meth:`ShapeModel.project` aligns a new shape)
    source      () str, "registered" (the registered templates) or "neutral" (their
                expression-removed shapes)
    total_variance () float64, mm^2, the variance of all the modes, kept or not
    version     () int, 1
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The layout version written in ``version``.
FORMAT_VERSION = 1
_REQUIRED = ("mean", "components", "variances", "n_scans", "faces", "names")


@dataclass
class ShapeModel:
    """A PCA shape model (see the module docstring for the fields and their units).

    Attributes
    ----------
    mean : (N, 3) mm; components : (K, N, 3) orthonormal; variances : (K,) mm^2 descending;
    faces : (M, 3) int; names : list of str (one per training shape); n_scans : int;
    scores : (n_scans, K) the training shapes' coefficients (standard deviations) or None;
    alignment : "rigid" | "similarity"; source : "registered" | "neutral";
    total_variance : mm^2, all the modes' variance (>= variances.sum()).
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    faces: np.ndarray
    names: list = field(default_factory=list)
    n_scans: int = 0
    scores: np.ndarray | None = None
    alignment: str = "rigid"
    source: str = "registered"
    total_variance: float | None = None

    def __post_init__(self):
        self.mean = np.asarray(self.mean, dtype=np.float64)
        self.components = np.asarray(self.components, dtype=np.float64).reshape(-1, *self.mean.shape)
        self.variances = np.asarray(self.variances, dtype=np.float64).reshape(-1)
        self.faces = np.asarray(self.faces, dtype=np.int64)
        self.names = [str(n) for n in self.names]
        if self.total_variance is None:
            self.total_variance = float(self.variances.sum())

    # --- sizes ---------------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        return len(self.mean)

    @property
    def n_modes(self) -> int:
        return len(self.variances)

    @property
    def std(self) -> np.ndarray:
        """(K,) standard deviations (mm) of the modes."""
        return np.sqrt(self.variances)

    def explained_variance(self) -> np.ndarray:
        """(K,) each mode's share of the total variance."""
        return self.variances / self.total_variance if self.total_variance > 0 else np.zeros(self.n_modes)

    # --- shapes ------------------------------------------------------------------------------------
    def sample(self, coefficients=()) -> np.ndarray:
        """The shape (N, 3) mm, model frame, with the given coefficients (standard deviations)
        on the first ``len(coefficients)`` modes and 0 on the others; ``()`` gives the mean."""
        a = np.asarray(coefficients, dtype=np.float64).reshape(-1)
        if len(a) > self.n_modes:
            raise ValueError(f"ShapeModel.sample: {len(a)} coefficients for a model of {self.n_modes} modes")
        k = len(a)
        return self.mean + np.tensordot(a * self.std[:k], self.components[:k], axes=1)

    def align(self, vertices):
        """``vertices`` (N, 3) mm fitted onto the mean the way the model's shapes were (rigid or
        similarity). Returns (aligned (N, 3), (R, s, t)) with ``aligned = s * vertices @ R.T + t``."""
        from ..geometry.transforms import kabsch

        v = self._check(vertices, "align")
        if self.alignment == "similarity":
            r, s, t = kabsch(v, self.mean, with_scale=True)
        else:
            (r, t), s = kabsch(v, self.mean), 1.0
        return s * v @ r.T + t, (r, s, t)

    def project(self, vertices, n_modes: int | None = None):
        """The model's closest shape to ``vertices`` (N, 3) mm, in the template's vertex order.

        The input is first aligned to the mean (:meth:`align`), so its pose (and, for a
        similarity model, its size) does not count. ``n_modes``: use only the first modes.

        Returns
        -------
        (coefficients (K,) in standard deviations, reconstruction (N, 3) mm in the input's own
        frame: the aligned reconstruction moved back by the inverse of the alignment).
        """
        k = self.n_modes if n_modes is None else int(min(max(n_modes, 0), self.n_modes))
        aligned, (r, s, t) = self.align(vertices)
        comps = self.components[:k].reshape(k, 3 * self.n_vertices)
        b = comps @ (aligned - self.mean).reshape(-1)
        recon = self.mean + (b @ comps).reshape(self.mean.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            alpha = np.where(self.variances[:k] > 0, b / self.std[:k], 0.0)
        return alpha, ((recon - t) @ r) / s

    def mahalanobis(self, vertices, n_modes: int | None = None) -> float:
        """The Mahalanobis distance of ``vertices`` (N, 3) mm from the mean within the model:
        sqrt(sum alpha_k^2) over its coefficients (after alignment; what the modes cannot
        express, the residual, does not count)."""
        alpha, _ = self.project(vertices, n_modes)
        return float(np.sqrt(np.sum(alpha ** 2)))

    def _check(self, vertices, who: str) -> np.ndarray:
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != self.mean.shape:
            from ..errors import ShapeModelError

            raise ShapeModelError(f"ShapeModel.{who}: vertices are {v.shape}, the model's shapes are "
                                  f"{self.mean.shape} (template vertex order, mm)")
        if not np.isfinite(v).all():
            from ..errors import ShapeModelError

            raise ShapeModelError(f"ShapeModel.{who}: vertices hold NaN or inf")
        return v

    # --- files ---------------------------------------------------------------------------------
    def arrays(self) -> dict:
        """The npz contents (module docstring)."""
        k = self.n_modes
        scores = self.scores if self.scores is not None else np.zeros((0, k))
        return {
            "mean": self.mean, "components": self.components, "variances": self.variances,
            "n_scans": np.int64(self.n_scans), "faces": self.faces,
            "names": np.array(self.names, dtype=str).reshape(-1), "scores": np.asarray(scores, np.float64),
            "alignment": np.array(self.alignment), "source": np.array(self.source),
            "total_variance": np.float64(self.total_variance), "version": np.int64(FORMAT_VERSION),
        }

    def save(self, path) -> None:
        """Write the model to ``path`` (.npz), atomically (complete or absent)."""
        from ..errors import OutputError
        from ..io.atomic import atomic_paths, check_output_paths

        path = Path(path)
        if path.suffix.lower() != ".npz":
            raise OutputError(f"{path}: a shape model is written as .npz")
        check_output_paths([("the model", path)])
        with atomic_paths(path) as (tmp,):
            with open(tmp, "wb") as fh:  # a file object: numpy must not append another .npz
                np.savez(fh, **self.arrays())

    @classmethod
    def load(cls, path) -> "ShapeModel":
        """Read a model written by :meth:`save`. Raises ShapeModelError (one line, naming the
        file) for a missing, unreadable or inconsistent file."""
        from ..errors import ShapeModelError

        path = Path(path)
        if not path.is_file():
            raise ShapeModelError(f"{path}: no such shape model file")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except Exception as e:  # noqa: BLE001 - any reader failure is a broken file
            raise ShapeModelError(f"{path}: not a shape model npz ({type(e).__name__}: "
                                  f"{str(e).splitlines()[0] if str(e) else ''})") from None
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise ShapeModelError(f"{path}: not a facecorr shape model (missing {', '.join(missing)})")
        if int(data.get("version", FORMAT_VERSION)) > FORMAT_VERSION:
            raise ShapeModelError(f"{path}: shape model format {int(data['version'])} is newer than this "
                                  f"facecorr reads ({FORMAT_VERSION}): upgrade facecorr")
        mean, comps, var = data["mean"], data["components"], data["variances"]
        if mean.ndim != 2 or mean.shape[1] != 3 or comps.ndim != 3 or comps.shape[1:] != mean.shape \
                or var.shape != (len(comps),):
            raise ShapeModelError(f"{path}: inconsistent shape model (mean {mean.shape}, components "
                                  f"{comps.shape}, variances {var.shape})")
        faces = data["faces"]
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and (faces.min() < 0 or faces.max() >= len(mean))):
            raise ShapeModelError(f"{path}: the faces do not index the model's {len(mean)} vertices")
        scores = data.get("scores")
        if scores is not None and scores.size == 0:
            scores = None
        return cls(mean=mean, components=comps, variances=var, faces=faces,
                   names=[str(n) for n in data["names"].reshape(-1)], n_scans=int(data["n_scans"]),
                   scores=scores, alignment=str(data.get("alignment", "rigid")),
                   source=str(data.get("source", "registered")),
                   total_variance=float(data["total_variance"]) if "total_variance" in data else None)
