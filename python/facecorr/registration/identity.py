"""Identity basis: a PCA of face shapes learned from a training database, fitted with the expression.

Why: the template is one face (the ICT mean) and the 14 blendshapes only move it by expression.
Every other difference between a subject and the template — a longer nose, higher brows, a wider
mouth — has to be absorbed by the shape fit, whose data term only pulls *across* the surface: the
template lands on the scan's surface but slides along it, and vertex k ends up millimetres away
from its true point (measured on 14 synthetic test scans with ground-truth landmarks: dense error
3.04 mm with the mean face, 0.93 mm when the template is given the subject's true identity).
Fitting a few dozen identity modes together with the blendshape weights (:mod:`.expression`) moves
the template to the subject's shape *with* its correspondence before the shape fit refines it.

The modes are learned from the training split of a database with dense ground truth, the way the
landmark model is learned from its landmarks (``facecorr train-identity DB``): each training scan's
dense correspondence (scan vertex = barycentric point of a template triangle) is turned into the
template's vertex positions on that scan (:func:`.identity_training.reconstruct_template`), rigidly aligned to the
template (Kabsch), and the displacements from the template are summarised by PCA
(:func:`.identity_training.train_identity_basis`). All training scans count, expressive ones too, and their
expression is left in (``remove_expression=False``): the modes then also carry the expression
variation the 14 blendshapes cannot express (squinting cheeks, lip shapes), which otherwise the
fit imitates with wrong blendshapes (brows pulled down for a squint). Measured on 14 synthetic
test scans with ground-truth landmarks (dense error, mm, the best settings found for each): mean
face 3.04; 40 modes learned with the blendshape part removed 1.68; 40 modes of the raw shapes 1.47.

On real data the same file is built from any registered database (template vertex order) with
:func:`.identity_training.basis_from_shapes`; the packaged basis is learned from synthetic faces of the ICT model
and is a prior for faces like them, not for every population.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np


#: Packaged basis, learned from the training split (50 subjects, neutral + 6 expressions) of the
#: synthetic bu3dfe database, seed 0 (see ``facecorr train-identity``).
IDENTITY_BASIS_PATH = Path(__file__).resolve().parent.parent / "data" / "identity_basis.npz"


@dataclass(frozen=True)
class IdentityBasis:
    """A linear shape model on the template's vertices.

    Attributes
    ----------
    mean : (N, 3) float64, mean displacement from the template's vertices, mm.
    modes : (M, N, 3) float64, displacement modes scaled to one standard deviation, mm (so the
        weights of a training shape are ~ N(0, 1)).
    n_samples : int, shapes the PCA was learned from.
    explained : (M,) float64, share of the training variance of each mode.
    """

    mean: np.ndarray
    modes: np.ndarray
    n_samples: int
    explained: np.ndarray

    @property
    def n_modes(self) -> int:
        return len(self.modes)

    def truncated(self, n_modes: int) -> "IdentityBasis":
        """The first ``n_modes`` modes."""
        n = max(0, min(int(n_modes), self.n_modes))
        return IdentityBasis(self.mean, self.modes[:n], self.n_samples, self.explained[:n])

    def save(self, path) -> None:
        from ..io.atomic import atomic_path

        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                # uncompressed: float32 modes deflate by only ~7 %, and inflating them cost
                # ~10 ms per basis at every `facecorr register` (three bases are read)
                np.savez(fh, mean=self.mean.astype(np.float32), modes=self.modes.astype(np.float32),
                         n_samples=np.int64(self.n_samples), explained=self.explained)


def load_identity_basis(path=None, n_vertices: int | None = None) -> IdentityBasis:
    """Load a basis written by :meth:`IdentityBasis.save` (default: the packaged one, read once
    per process and shared, its arrays read-only)."""
    b = _packaged_basis() if path is None else _read_basis(Path(path))
    if n_vertices is not None and len(b.mean) != n_vertices:
        from ..errors import FacecorrError

        raise FacecorrError(f"identity basis {path or IDENTITY_BASIS_PATH} has {len(b.mean)} vertices, "
                            f"the template {n_vertices}")
    return b


@functools.lru_cache(maxsize=1)
def _packaged_basis() -> IdentityBasis:
    b = _read_basis(IDENTITY_BASIS_PATH)  # 50 ms: worth keeping for a batch of registrations
    for a in (b.mean, b.modes, b.explained):
        a.flags.writeable = False
    return b


def _read_basis(p: Path) -> IdentityBasis:
    from ..errors import FacecorrError

    try:
        with np.load(p) as d:
            b = IdentityBasis(mean=d["mean"].astype(np.float64), modes=d["modes"].astype(np.float64),
                              n_samples=int(d["n_samples"]), explained=d["explained"].astype(np.float64))
    except (OSError, KeyError, ValueError) as e:
        raise FacecorrError(f"cannot read identity basis {p}: {e}") from None
    if b.modes.ndim != 3 or b.modes.shape[1:] != b.mean.shape or b.mean.shape[1:] != (3,):
        raise FacecorrError(f"identity basis {p} has inconsistent shapes {b.mean.shape}, {b.modes.shape}")
    return b


def __getattr__(name):
    # Deprecated aliases (one release): training moved to :mod:`.identity_training`.
    if name in ("basis_from_shapes", "reconstruct_template", "train_identity_basis"):
        import warnings

        from . import identity_training

        warnings.warn(f"facecorr.registration.identity.{name} moved to "
                      f"facecorr.registration.identity_training.{name}", DeprecationWarning, stacklevel=2)
        return getattr(identity_training, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
