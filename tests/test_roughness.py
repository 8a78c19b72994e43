"""Surface roughness (facecorr.geometry.roughness) against analytic answers."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr.geometry.roughness import diffusion_steps, smooth_over, surface_roughness, vertex_adjacency


def grid(n=80, h=1.0):
    """A flat n×n grid of spacing h (mm) in z = 0, split into triangles: (V, F, edges)."""
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h)
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    return v, f, e


def test_flat_plane_is_smooth():
    v, _, e = grid()
    r = surface_roughness(v, e, np.tile([0.0, 0.0, 1.0], (len(v), 1)))
    assert np.abs(r).max() < 1e-12


@pytest.mark.parametrize("sigma", [0.1, 0.5, 1.0])
def test_gaussian_noise_matches_the_analytic_mean(sigma):
    # iid N(0, σ²) heights: v − mean of k neighbours is N(0, σ²(1 + 1/k)), whose mean absolute
    # value is σ sqrt(2/π) sqrt(1 + 1/k); interior grid vertices have k = 6.
    v, _, e = grid(120)
    rng = np.random.default_rng(0)
    v[:, 2] = rng.normal(0.0, sigma, len(v))
    r = surface_roughness(v, e, np.tile([0.0, 0.0, 1.0], (len(v), 1)), radius=2.0)
    interior = ((v[:, 0] > 10) & (v[:, 0] < 109) & (v[:, 1] > 10) & (v[:, 1] < 109))
    expected = sigma * np.sqrt(2.0 / np.pi) * np.sqrt(1.0 + 1.0 / 6.0)
    assert np.median(r[interior]) == pytest.approx(expected, rel=0.05)


def test_sphere_roughness_is_its_curvature_share():
    # A fine sphere of radius R: the umbrella Laplacian is ~ h²/(2R) per unit edge, far below
    # any noise a scanner or a beard adds.
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=5, radius=80.0)
    v = np.asarray(s.vertices)
    r = surface_roughness(v, np.asarray(s.edges_unique), v / 80.0, radius=2.5)
    h = float(np.asarray(s.edges_unique_length).mean())
    assert np.median(r) == pytest.approx(h * h / (2 * 80.0), rel=0.25)
    assert r.max() < 0.1


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 12), st.floats(0.1, 5.0))
def test_smoothing_keeps_constants_and_bounds(n_iter, c):
    v, _, e = grid(12)
    a = vertex_adjacency(len(v), e)
    assert np.allclose(smooth_over(a, np.full(len(v), c), n_iter), c)
    rng = np.random.default_rng(n_iter)
    x = rng.uniform(0, c, len(v))
    y = smooth_over(a, x, n_iter)
    assert y.min() >= x.min() - 1e-12 and y.max() <= x.max() + 1e-12


def test_smoothing_matches_a_dense_reference():
    v, _, e = grid(9)
    a = vertex_adjacency(len(v), e)
    dense = np.zeros((len(v), len(v)))
    dense[e[:, 0], e[:, 1]] = dense[e[:, 1], e[:, 0]] = 1.0
    dense += np.eye(len(v))
    x = np.random.default_rng(1).normal(size=len(v))
    ref = x.copy()
    for _ in range(3):
        ref = dense @ ref / dense.sum(1)
    assert np.allclose(smooth_over(a, x, 3), ref, atol=1e-12)


def test_diffusion_steps_scale_with_resolution():
    assert diffusion_steps(1.0, 2.5) == 7
    assert diffusion_steps(0.5, 2.5) == 25
    assert diffusion_steps(5.0, 2.5) == 1
    assert diffusion_steps(0.01, 2.5) == 80
