"""Identity basis (facecorr.registration.identity) and its fit together with the expression."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facecorr.errors import FacecorrError
from facecorr.geometry.transforms import kabsch
from facecorr.geometry.mesh import Mesh
from facecorr.registration.expression import fit_expression
from facecorr.registration.identity import IdentityBasis, load_identity_basis
from facecorr.registration.identity_training import basis_from_shapes, reconstruct_template
from facecorr.template import load_template


def _rotation(rng):
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.linalg.det(q))


def _smooth_fields(template, m, rng, amplitude=3.0):
    """(m, N, 3) smooth displacement fields (random Gaussian bumps), mm."""
    v = np.asarray(template.vertices)
    out = np.zeros((m, len(v), 3))
    for i in range(m):
        for _ in range(3):
            c = v[rng.integers(len(v))]
            bump = np.exp(-np.sum((v - c) ** 2, axis=1) / (2 * 25.0**2))
            out[i] += bump[:, None] * rng.normal(0, amplitude, 3)
    return out


def test_basis_from_shapes_matches_numpy_pca():
    """Shapes in random poses: the basis equals a plain SVD of the aligned displacements."""
    tpl = load_template()
    rng = np.random.default_rng(0)
    a0 = np.asarray(tpl.vertices)
    fields = _smooth_fields(tpl, 4, rng)
    w = rng.standard_normal((12, 4)) * [4.0, 3.0, 2.0, 1.0]
    disp = np.tensordot(w, fields, axes=1)  # (12, N, 3)
    shapes = np.array([(a0 + d) @ _rotation(rng).T + rng.uniform(-50, 50, 3) for d in disp])
    b = basis_from_shapes(shapes, tpl, n_modes=4)
    # reference: align each shape by Kabsch (numpy SVD), then PCA by eigendecomposition
    ref = []
    for x in shapes:
        xc, ac = x - x.mean(0), a0 - a0.mean(0)
        u, _, vt = np.linalg.svd(xc.T @ ac)
        r = (u @ np.diag([1, 1, np.sign(np.linalg.det(u @ vt))]) @ vt).T
        ref.append((xc @ r.T + a0.mean(0) - a0).ravel())
    ref = np.array(ref)
    np.testing.assert_allclose(b.mean.ravel(), ref.mean(0), atol=1e-6)
    centred = ref - ref.mean(0)
    evals = np.linalg.eigvalsh(centred @ centred.T / (len(ref) - 1))  # = the covariance's nonzero ones
    evals = evals[::-1][:4]
    np.testing.assert_allclose((b.modes.reshape(4, -1) ** 2).sum(1), evals, rtol=1e-6)
    assert np.all(np.diff(b.explained) <= 0) and b.n_samples == 12
    # orthogonal modes; and as the poses hide little of the rank-4 displacements, they explain most
    m = b.modes.reshape(4, -1)
    gram = m @ m.T
    np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0.0, atol=1e-8 * gram.max())
    assert b.explained.sum() > 0.95, b.explained


def test_reconstruct_template_from_dense_ground_truth():
    """Scan points = barycentric points of a deformed, posed template: the deformation comes back."""
    tpl = load_template()
    rng = np.random.default_rng(1)
    a0 = np.asarray(tpl.vertices)
    faces = np.asarray(tpl.faces)
    x_true = a0 + _smooth_fields(tpl, 1, rng)[0]
    ict_of = np.full(len(faces), -1)
    mapped = np.flatnonzero(tpl.ict_face_to_template_face >= 0)
    ict_of[tpl.ict_face_to_template_face[mapped]] = mapped
    tri = rng.choice(np.flatnonzero(ict_of >= 0), size=40_000)
    bary = rng.dirichlet([1, 1, 1], size=len(tri))
    y = np.einsum("sk,skd->sd", bary, x_true[faces[tri]])
    r, t = _rotation(rng), np.array([10.0, 0.0, 400.0])
    dense = {"tri": ict_of[tri], "bary": bary, "clean": y @ r.T + t}
    x, observed = reconstruct_template(dense, tpl)
    r2, t2 = kabsch(x_true, a0)  # the reconstruction is in the template's best-fit pose
    err = np.linalg.norm(x - (x_true @ r2.T + t2), axis=1)
    assert observed.mean() > 0.99
    assert np.median(err[observed]) < 0.05 and err[observed].max() < 0.5, (np.median(err), err.max())
    with pytest.raises(ValueError, match="fewer than 100"):
        reconstruct_template({"tri": ict_of[tri[:50]], "bary": bary[:50], "clean": y[:50]}, tpl)


def _posed(tpl, alpha, beta, basis, rng):
    from synthetic_face import subdivide as _subdivided

    v = tpl.expression(alpha) + basis.mean + np.tensordot(beta, basis.modes, axes=1)
    v, f = _subdivided(v, np.asarray(tpl.faces))
    r, t = _rotation(rng), np.array([20.0, -40.0, 300.0])
    return Mesh(v @ r.T + t, f), r, t


def test_fit_expression_recovers_identity_and_expression_weights():
    tpl = load_template()
    rng = np.random.default_rng(2)
    fields = _smooth_fields(tpl, 3, rng, amplitude=2.0)
    basis = IdentityBasis(mean=np.zeros_like(fields[0]), modes=fields, n_samples=10, explained=np.full(3, 0.3))
    names = list(tpl.blendshape_names)
    alpha = np.zeros(tpl.n_blendshapes)
    alpha[names.index("jawOpen")], alpha[names.index("mouthSmile_L")] = 0.3, 0.6
    beta = np.array([1.5, -1.0, 0.8])
    scan, r, t = _posed(tpl, alpha, beta, basis, rng)
    # no priors: the weights are exact, so they must come back exactly
    res = fit_expression(tpl, np.hstack([r, t[:, None]]), scan, identity=basis, identity_prior=1e-3,
                         identity_prior_start=None, alpha_prior=0.0, max_rounds=40)
    np.testing.assert_allclose(res.alpha, alpha, atol=0.05)
    np.testing.assert_allclose(res.identity_weights, beta, atol=0.1)
    without = fit_expression(tpl, np.hstack([r, t[:, None]]), scan, alpha_prior=0.0)
    gt = tpl.expression(alpha) + np.tensordot(beta, fields, axes=1)
    err = lambda v: np.linalg.norm(v - (gt @ r.T + t), axis=1).mean()  # noqa: E731
    assert err(res.vertices) < 0.1 < err(without.vertices), (err(res.vertices), err(without.vertices))


def test_refine_rigid_corrects_a_misaligned_start():
    """Start 2 degrees and 1.5 mm off: refine_rigid brings the pose (and the weights) back."""
    tpl = load_template()
    rng = np.random.default_rng(3)
    names = list(tpl.blendshape_names)
    alpha = np.zeros(tpl.n_blendshapes)
    alpha[names.index("browInnerUp")] = 0.5
    zero = IdentityBasis(np.zeros((tpl.n_vertices, 3)), np.zeros((0, tpl.n_vertices, 3)), 1, np.zeros(0))
    scan, r, t = _posed(tpl, alpha, np.zeros(0), zero, rng)
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    from facecorr.geometry.transforms import rotation_from_vector as _rodrigues

    off = _rodrigues(np.radians(2.0) * axis)
    start = np.hstack([off @ r, (t + [1.5, 0, 0])[:, None]])
    truth = tpl.expression(alpha) @ r.T + t
    fixed = fit_expression(tpl, start, scan, alpha_prior=0.0, refine_rigid=False)
    # nearest-vertex ICP creeps along a rotation: 30 rounds here (the default 20 leaves 0.11 mm)
    refined = fit_expression(tpl, start, scan, alpha_prior=0.0, refine_rigid=True, max_rounds=40)
    e_fixed = np.linalg.norm(fixed.vertices - truth, axis=1).mean()
    e_ref = np.linalg.norm(refined.vertices - truth, axis=1).mean()
    assert e_ref < 0.05 < e_fixed, (e_ref, e_fixed)
    np.testing.assert_allclose(refined.transform[:, :3], r, atol=1e-3)
    np.testing.assert_allclose(refined.alpha, alpha, atol=0.03)


def test_packaged_basis_and_bad_files(tmp_path):
    tpl = load_template()
    b = load_identity_basis(n_vertices=tpl.n_vertices)
    assert b.modes.shape == (b.n_modes, tpl.n_vertices, 3) and b.n_modes >= 20 and b.n_samples >= 100
    assert np.all(np.isfinite(b.modes)) and 0.5 < b.explained.sum() <= 1.0
    p = tmp_path / "b.npz"
    b.truncated(5).save(p)
    b5 = load_identity_basis(p)
    np.testing.assert_allclose(b5.modes, b.modes[:5], atol=1e-4)
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    with pytest.raises(FacecorrError, match="cannot read identity basis"):
        load_identity_basis(tmp_path / "broken.npz")
    with pytest.raises(FacecorrError, match="vertices"):
        load_identity_basis(p, n_vertices=tpl.n_vertices + 1)


def test_a_fit_continued_where_it_stopped_matches_one_long_fit():
    """fit(3 rounds) continued (alpha0, beta0, transform, round_offset) ≈ fit(30 rounds)."""
    tpl = load_template()
    rng = np.random.default_rng(4)
    fields = _smooth_fields(tpl, 3, rng, amplitude=2.0)
    basis = IdentityBasis(mean=np.zeros_like(fields[0]), modes=fields, n_samples=10, explained=np.full(3, 0.3))
    alpha = np.zeros(tpl.n_blendshapes)
    alpha[list(tpl.blendshape_names).index("jawOpen")] = 0.4
    scan, r, t = _posed(tpl, alpha, np.array([1.0, 0.5, -1.0]), basis, rng)
    start = np.hstack([r, (t + [1.0, 0.0, 0.0])[:, None]])
    # (no over-relaxation, Anderson mixing or energy stop: they look at earlier rounds, which a
    # continuation starts without)
    opts = dict(identity=basis, identity_prior=1.0, identity_prior_start=100.0, alpha_tol=0.0, overrelax=1.0,
                energy_rtol=0.0, anderson=0)
    whole = fit_expression(tpl, start, scan, max_rounds=30, **opts)
    part = fit_expression(tpl, start, scan, max_rounds=3, **opts)
    rest = fit_expression(tpl, part.transform, scan, alpha0=part.alpha, beta0=part.identity_weights,
                          round_offset=3, max_rounds=27, **opts)
    assert len(whole.rounds) == 30 and len(part.rounds) + len(rest.rounds) == 30
    assert np.abs(rest.vertices - whole.vertices).max() < 0.05
    assert np.abs(rest.vertices - part.vertices).max() > 0.05  # the continuation did move it
