"""Learning the identity basis (see :mod:`.identity` for why and how it is fitted): the template's
vertex positions on each training scan from its dense ground truth, rigid alignment, PCA."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import _core
from ..geometry.transforms import kabsch
from .identity import IdentityBasis


def _edge_operator(faces: np.ndarray, n: int) -> sp.csr_matrix:
    """(E, N) sparse: +1 / -1 on the two ends of every template edge."""
    e = _core.mesh_edges(np.ascontiguousarray(faces, dtype=np.int64), n)
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
    from tqdm import tqdm

    it = tqdm(recs, desc="identity", disable=not progress)
    shapes = []
    for r in it:
        try:
            with np.load(r["dense"]) as d:
                x, _ = reconstruct_template(d, template)
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(f"{r.get('dense')}: cannot use its dense ground truth ({e})") from None
        shapes.append(x)
    return basis_from_shapes(np.array(shapes), template, n_modes=n_modes, remove_expression=remove_expression)


def train_expression_residual(db_dir, template=None, n_modes: int = 10, progress: bool = True) -> IdentityBasis:
    """Learn what the blendshapes miss of the expressions: an :class:`IdentityBasis` (mean zero) of
    expression displacements, for :func:`.neutral.neutral_shape`.

    For every training subject of a synthetic database with a neutral scan, each of its expressive
    scans' template shape (:func:`reconstruct_template` of the dense ground truth) is rigidly fitted
    onto the neutral one; their difference, less its bounded blendshape fit, is what the 14
    blendshapes cannot express (a disgust's nose wrinkle and raised upper lip). The modes are the
    principal directions of these residual displacements, about zero (no expression), scaled to
    one standard deviation, mm.

    Parameters
    ----------
    db_dir : folder written by ``facecorr synth`` (its ``index.json`` and ``*_dense.npz``); its
        training split only is read.
    template : Template (default: the packaged one).
    n_modes : modes kept.
    progress : show a progress bar.
    """
    from collections import defaultdict

    from tqdm import tqdm

    from ..synth import load_index
    from ..template import load_template

    template = template if template is not None else load_template()
    by_subject: dict = defaultdict(dict)
    for r in load_index(db_dir):
        if r.get("split") == "train":
            by_subject[r["subject"]].setdefault(r["expression"], []).append(r)
    pairs = [(recs["NE"][0], r) for _, recs in sorted(by_subject.items()) if "NE" in recs
             for e, rs in sorted(recs.items()) if e != "NE" for r in rs]
    if not pairs:
        raise ValueError(f"{db_dir}: no expressive training scan with a neutral scan of its subject")
    blend = np.asarray(template.blendshapes, dtype=np.float64)
    neutral_of: dict = {}
    disp = []
    for ne, r in tqdm(pairs, desc="expression residual", disable=not progress):
        try:
            if ne["dense"] not in neutral_of:
                with np.load(ne["dense"]) as d:
                    neutral_of[ne["dense"]] = reconstruct_template(d, template)[0]
            with np.load(r["dense"]) as d:
                x, _ = reconstruct_template(d, template)
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(f"{r.get('dense')}: cannot use its dense ground truth ({e})") from None
        xn = neutral_of[ne["dense"]]
        rot, t = kabsch(x, xn)
        disp.append(_remove_expression(x @ rot.T + t - xn, blend).ravel())
    disp = np.array(disp)
    _, sv, vt = np.linalg.svd(disp, full_matrices=False)  # about zero: "no expression" is the origin
    m = max(1, min(int(n_modes), len(disp)))
    std = sv[:m] / np.sqrt(len(disp))
    var = sv ** 2
    return IdentityBasis(mean=np.zeros_like(template.vertices, dtype=np.float64),
                         modes=(vt[:m] * std[:, None]).reshape(m, -1, 3), n_samples=len(disp),
                         explained=var[:m] / var.sum())
