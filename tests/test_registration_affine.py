"""Landmark alignment (paper §4.1)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr.errors import RegistrationError
from facecorr.registration.alignment import affine_lstsq, affine_quasi_newton, align_landmarks, apply_transform, landmark_energy, similarity_umeyama
from facecorr.template import load_template


def rotation(rng):
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.linalg.det(q))


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000))
def test_quasi_newton_equals_closed_form(seed):
    rng = np.random.default_rng(seed)
    src = load_template().vertices[load_template().landmark_ids]
    t_true = np.hstack([rotation(rng) * rng.uniform(0.8, 1.2) + 0.1 * rng.standard_normal((3, 3)),
                        rng.uniform(-500, 500, (3, 1))])
    dst = apply_transform(t_true, src) + rng.normal(0, 2.0, src.shape)
    qn = affine_quasi_newton(src, dst)
    ls = affine_lstsq(src, dst)
    assert landmark_energy(qn, src, dst) == pytest.approx(landmark_energy(ls, src, dst), rel=1e-7, abs=1e-7)
    np.testing.assert_allclose(qn, ls, rtol=1e-5, atol=1e-5 * np.abs(ls).max())


def test_similarity_recovers_a_similarity_exactly():
    rng = np.random.default_rng(3)
    src = load_template().vertices[load_template().landmark_ids]
    r, s, t = rotation(rng), 1.13, np.array([10.0, -200.0, 35.0])
    dst = s * src @ r.T + t
    for mode in ("similarity", "affine", "similarity+affine"):
        np.testing.assert_allclose(align_landmarks(src, dst, mode=mode), np.hstack([s * r, t[:, None]]), atol=1e-6)


def test_similarity_does_not_shear_under_landmark_noise():
    rng = np.random.default_rng(7)
    tpl = load_template()
    src = tpl.vertices[tpl.landmark_ids]
    r = rotation(rng)
    dst = src @ r.T + rng.normal(0, 2.0, src.shape)
    sim = similarity_umeyama(src, dst)
    aff = affine_lstsq(src, dst)
    # singular values of the linear part: a similarity's are all equal
    sv_sim = np.linalg.svd(sim[:, :3], compute_uv=False)
    sv_aff = np.linalg.svd(aff[:, :3], compute_uv=False)
    assert sv_sim.max() / sv_sim.min() == pytest.approx(1.0)
    assert sv_aff.max() / sv_aff.min() > sv_sim.max() / sv_sim.min()


def test_mirrored_or_bad_landmarks_are_errors():
    tpl = load_template()
    src = tpl.vertices[tpl.landmark_ids]
    with pytest.raises(RegistrationError, match="mirrored"):
        align_landmarks(src, src * [-1, 1, 1], mode="affine")
    with pytest.raises(ValueError, match="NaN"):
        align_landmarks(src, np.full_like(src, np.nan))
    with pytest.raises(RegistrationError, match="collinear"):
        align_landmarks(src, np.outer(np.arange(8.0), [1, 0, 0]))
    with pytest.raises(ValueError, match="mode"):
        align_landmarks(src, src, mode="rigid")
