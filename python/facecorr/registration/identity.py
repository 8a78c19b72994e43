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
template's vertex positions on that scan (:func:`reconstruct_template`), rigidly aligned to the
template (Kabsch), and the displacements from the template are summarised by PCA
(:func:`train_identity_basis`). All training scans count, expressive ones too, and their
expression is left in (``remove_expression=False``): the modes then also carry the expression
variation the 14 blendshapes cannot express (squinting cheeks, lip shapes), which otherwise the
fit imitates with wrong blendshapes (brows pulled down for a squint). Measured on 14 synthetic
test scans with ground-truth landmarks (dense error, mm, the best settings found for each): mean
face 3.04; 40 modes learned with the blendshape part removed 1.68; 40 modes of the raw shapes 1.47.

On real data the same file is built from any registered database (template vertex order) with
:func:`basis_from_shapes`; the packaged basis is learned from synthetic faces of the ICT model
and is a prior for faces like them, not for every population.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..landmarks.alignment import kabsch

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
        from ..fileio import atomic_path

        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, mean=self.mean.astype(np.float32), modes=self.modes.astype(np.float32),
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


def _edge_operator(faces: np.ndarray, n: int) -> sp.csr_matrix:
    """(E, N) sparse: +1 / -1 on the two ends of every template edge."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    rows = np.repeat(np.arange(len(e)), 2)
    vals = np.tile([1.0, -1.0], len(e))
    return sp.csr_matrix((vals, (rows, e.ravel())), shape=(len(e), n))


def reconstruct_template(dense, template, smooth: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
    """The template's vertex positions on a scan, from its dense ground truth, in the template frame.

    Solves min_X Σ_s ‖Σ_c b_sc X[f_sc] − y_s‖² + smooth Σ_edges ‖(X_i − X_j) − (A0_i − A0_j)‖²,
    where scan vertex s (noise-free position y_s, rigidly aligned to the template beforehand) is
    the barycentric point b_s of template face f_s; the membrane term fills vertices no scan
    vertex touches (holes, the template's border) with the template's own shape.

    Parameters
    ----------
    dense : mapping with ``tri`` (S,), ``bary`` (S, 3), ``clean`` (S, 3) (the synthetic
        database's ``*_dense.npz``, see :func:`facecorr.evaluate.dense_error`).
    template : Template.
    smooth : weight of the membrane term (per edge, relative to one observation).

    Returns
    -------
    (X (N, 3) mm in the template frame, observed (N,) bool: vertices of a face some scan vertex
    lies on).
    """
    a0 = np.asarray(template.vertices, dtype=np.float64)
    n = len(a0)
    faces = np.asarray(template.faces, dtype=np.int64)
    face = template.ict_face_to_template_face[np.asarray(dense["tri"]).astype(np.int64)]
    mask = face >= 0
    if mask.sum() < 100:
        raise ValueError("dense ground truth: fewer than 100 scan vertices on the template")
    corners = faces[face[mask]]
    bary = np.asarray(dense["bary"], dtype=np.float64)[mask]
    y = np.asarray(dense["clean"], dtype=np.float64)[mask]
    # rigid pose from the template's mean shape at the same surface points
    src = np.einsum("sk,skd->sd", bary, a0[corners])
    r, t = kabsch(y, src)
    y = y @ r.T + t
    s = len(y)
    a = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(s), 3), corners.ravel())), shape=(s, n))
    g = _edge_operator(faces, n)
    lap = (g.T @ g).tocsc()
    lhs = (a.T @ a + smooth * lap).tocsc()
    rhs = a.T @ y + smooth * (lap @ a0)
    x = spla.splu(lhs).solve(np.asarray(rhs))
    observed = np.zeros(n, dtype=bool)
    observed[corners.ravel()] = True
    # a final rigid fit of the whole reconstruction (the first used only the observed part)
    r2, t2 = kabsch(x, a0)
    return x @ r2.T + t2, observed


def _remove_expression(d: np.ndarray, blendshapes: np.ndarray) -> np.ndarray:
    """d (N, 3) minus its bounded (α ∈ [0, 1]) least-squares blendshape part."""
    from .expression import box_qp

    j = blendshapes.reshape(len(blendshapes), -1).T  # (3N, K)
    alpha = box_qp(j.T @ j, j.T @ d.ravel(), np.zeros(j.shape[1]))
    return d - (j @ alpha).reshape(d.shape)


def basis_from_shapes(shapes, template, n_modes: int = 40, remove_expression: bool = False) -> IdentityBasis:
    """PCA of registered shapes (template vertex order, any rigid pose) as an :class:`IdentityBasis`.

    Parameters
    ----------
    shapes : (S, N, 3) template vertex positions on S training scans, mm.
    template : Template.
    n_modes : modes kept (at most S − 1).
    remove_expression : subtract each shape's bounded blendshape fit first (keeps identity only;
        measured worse, see the module docstring).
    """
    a0 = np.asarray(template.vertices, dtype=np.float64)
    shapes = np.asarray(shapes, dtype=np.float64)
    if shapes.ndim != 3 or shapes.shape[1:] != a0.shape or len(shapes) < 2:
        raise ValueError(f"shapes must be (S >= 2, {len(a0)}, 3), got {shapes.shape}")
    bs = np.asarray(template.blendshapes, dtype=np.float64)
    disp = []
    for x in shapes:
        r, t = kabsch(x, a0)
        d = x @ r.T + t - a0
        disp.append(_remove_expression(d, bs) if remove_expression else d)
    disp = np.array(disp).reshape(len(shapes), -1)
    mean = disp.mean(axis=0)
    _, sv, vt = np.linalg.svd(disp - mean, full_matrices=False)
    m = max(1, min(int(n_modes), len(shapes) - 1))
    std = sv[:m] / np.sqrt(len(shapes) - 1)
    var = sv**2
    return IdentityBasis(mean=mean.reshape(-1, 3), modes=(vt[:m] * std[:, None]).reshape(m, -1, 3),
                         n_samples=len(shapes), explained=var[:m] / var.sum())


def train_identity_basis(db_dir, template=None, n_modes: int = 40, neutral_only: bool = False,
                         progress: bool = True, remove_expression: bool = False) -> IdentityBasis:
    """Learn an :class:`IdentityBasis` from the training split of a synthetic database.

    Parameters
    ----------
    db_dir : folder written by ``facecorr synth`` (its ``index.json`` and ``*_dense.npz``).
    template : Template (default: the packaged one).
    n_modes : modes kept.
    neutral_only : learn from the neutral scans only (one per subject) instead of every scan.
    progress : show a progress bar.
    remove_expression : see :func:`basis_from_shapes`.
    """
    from ..synth import load_index
    from ..template import load_template

    template = template if template is not None else load_template()
    recs = [r for r in load_index(db_dir) if r.get("split") == "train"]
    if neutral_only:
        recs = [r for r in recs if r["expression"] == "NE"]
    if len(recs) < 2:
        raise ValueError(f"{db_dir}: fewer than 2 training scans with dense ground truth")
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        tqdm = None
    it = tqdm(recs, desc="identity", disable=not progress) if tqdm else recs
    shapes = []
    for r in it:
        try:
            with np.load(r["dense"]) as d:
                x, _ = reconstruct_template(d, template)
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(f"{r.get('dense')}: cannot use its dense ground truth ({e})") from None
        shapes.append(x)
    return basis_from_shapes(np.array(shapes), template, n_modes=n_modes, remove_expression=remove_expression)
