"""The expression fit's per-round normal equations (Rust ``_core.blend_normal_equations`` plus the
Gram-updated point-to-point block) against a plain numpy reference that builds every vertex's
Jacobian S_i (3, n_x) explicitly, as the expression fit did before the kernel existed."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr import _core
from facecorr.registration.expression import _BlendBasis, _WeightedGram, _normal_equations


def reference(cols, lin, w, da, qn, v, lam, rigid):
    """H, g, c of E(x) = Σ w_i [(1 − λ)(⟨da_i, n_i⟩ − n_iᵀS_i x)² + λ‖da_i − S_i x‖²], all blocks."""
    k = len(cols)
    a_cols = cols.transpose(1, 2, 0)  # (N, 3, K)
    n_x = k + (6 if rigid else 0)
    s = np.zeros((len(w), 3, n_x))
    s[:, :, :k] = np.matmul(lin, a_cols)
    if rigid:
        s[:, 0, k + 1], s[:, 0, k + 2] = v[:, 2], -v[:, 1]
        s[:, 1, k + 0], s[:, 1, k + 2] = -v[:, 2], v[:, 0]
        s[:, 2, k + 0], s[:, 2, k + 1] = v[:, 1], -v[:, 0]
        s[:, :, k + 3:] = np.eye(3)
    j = np.einsum("nd,ndx->nx", qn, s)
    c = np.einsum("nd,nd->n", da, qn)
    pw, lw = (1 - lam) * w, lam * w
    h = j.T @ (j * pw[:, None]) + np.einsum("n,ndx,ndy->xy", lw, s, s)
    g = j.T @ (pw * c) + np.einsum("n,ndx,nd->x", lw, s, da)
    const = float(pw @ (c * c) + lw @ np.einsum("nd,nd->n", da, da))
    return h, g, const


def problem(seed, n=60, k=7, similarity=True):
    rng = np.random.default_rng(seed)
    cols = rng.normal(0, 1, (k, n, 3))
    if similarity:
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        lin = 1.3 * q * np.sign(np.linalg.det(q))
    else:
        lin = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    w = np.where(rng.random(n) < 0.25, 0.0, rng.uniform(0.2, 1.5, n))
    da = rng.normal(0, 3, (n, 3))
    qn = rng.normal(size=(n, 3))
    qn /= np.linalg.norm(qn, axis=1, keepdims=True)
    v = rng.normal(0, 40, (n, 3))
    return cols, lin, w, da, qn, v


@pytest.mark.parametrize("similarity", [True, False])
@pytest.mark.parametrize("rigid", [True, False])
@pytest.mark.parametrize("lam", [0.0, 0.3])
def test_normal_equations_match_numpy_reference(similarity, rigid, lam):
    cols, lin, w, da, qn, v = problem(3, similarity=similarity)
    basis = _BlendBasis(cols)
    h, g, c = _normal_equations(basis, _WeightedGram(basis), lin, w, da, qn, v, lam, rigid)
    hr, gr, cr = reference(cols, lin, w, da, qn, v, lam, rigid)
    scale = np.abs(hr).max()
    np.testing.assert_allclose(h, hr, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(g, gr, rtol=0, atol=1e-11 * np.abs(gr).max())
    assert c == pytest.approx(cr, rel=1e-12)
    np.testing.assert_allclose(h, h.T, rtol=0, atol=1e-12 * scale)


def test_gram_follows_changing_weights():
    """The point-to-point block updated through the vertices whose weight changed equals the
    full sum, round after round (weights switching on and off, and continuous ones)."""
    cols, lin, w, da, qn, v = problem(5, n=80)
    basis = _BlendBasis(cols)
    gram = _WeightedGram(basis)
    rng = np.random.default_rng(0)
    for _ in range(6):
        w = np.where(rng.random(len(w)) < 0.1, rng.uniform(0, 1, len(w)) * (rng.random(len(w)) < 0.7), w)
        h, g, c = _normal_equations(basis, gram, lin, w, da, qn, v, 0.3, True)
        hr, _, _ = reference(cols, lin, w, da, qn, v, 0.3, True)
        np.testing.assert_allclose(h, hr, rtol=0, atol=1e-11 * np.abs(hr).max())


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40), k=st.integers(1, 9), lam=st.floats(0.0, 0.95),
       rigid=st.booleans())
def test_quadratic_form_is_the_energy(seed, n, k, lam, rigid):
    """xᵀHx − 2gᵀx + c reproduces the energy summed from its definition at random x."""
    cols, lin, w, da, qn, v = problem(seed, n=n, k=k, similarity=seed % 2 == 0)
    basis = _BlendBasis(cols)
    h, g, c = _normal_equations(basis, _WeightedGram(basis), lin, w, da, qn, v, lam, rigid)
    x = np.random.default_rng(seed).normal(0, 0.5, len(g))
    disp = (basis.flat @ x[:k]).reshape(-1, 3) @ lin.T
    if rigid:
        disp = disp + np.cross(x[k:k + 3], v) + x[k + 3:]
    rp = np.einsum("nd,nd->n", da - disp, qn)
    e = float(w @ ((1 - lam) * rp**2 + lam * np.einsum("nd,nd->n", da - disp, da - disp)))
    assert float(x @ h @ x - 2 * g @ x + c) == pytest.approx(e, rel=1e-9, abs=1e-9)


def test_bad_input_is_a_value_error():
    cols, lin, w, da, qn, v = problem(1)
    basis = _BlendBasis(cols)
    with pytest.raises(ValueError, match="shape"):
        _core.blend_normal_equations(basis.flat, lin, w, da[:-1], qn, v, 0.3, True)
    bad = da.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        _core.blend_normal_equations(basis.flat, lin, w, bad, qn, v, 0.3, True)
    for where, value in [(0, np.inf), (7, -np.inf), (-1, np.nan), (-3, np.inf)]:  # in the 8-lane body / tail
        flat = basis.flat.copy()
        flat.reshape(-1)[where] = value
        with pytest.raises(ValueError, match="NaN or infinite"):
            _core.blend_normal_equations(flat, lin, w, da, qn, v, 0.3, True)
    huge = basis.flat * 1e300  # finite, however large
    _core.blend_normal_equations(huge, lin, w, da, qn, v, 0.3, True)
    with pytest.raises(ValueError, match="lam"):
        _core.blend_normal_equations(basis.flat, lin, w, da, qn, v, 1.0, True)
    with pytest.raises(ValueError, match="contiguous"):
        _core.blend_normal_equations(basis.flat, lin, w, np.asfortranarray(da), qn, v, 0.3, True)
