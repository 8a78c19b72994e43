"""Shape fitting (Rust) against the numpy reference tests/ref_shape_fit.py, and end to end."""

from dataclasses import asdict

import numpy as np
import pytest

from facecorr import _core
from facecorr.geometry.mesh import Mesh
from facecorr.registration.shape import ShapeFitOptions, fit_shape

from ref_shape_fit import shape_energy


def grid(nx, ny, h, height):
    x, y = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h)
    v = np.stack([x.ravel(), y.ravel(), height(x.ravel(), y.ravel())], axis=1)
    f = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a = j * nx + i
            f += [[a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]]
    return v, np.array(f, dtype=np.int64)


def random_problem(seed, n_side=6):
    rng = np.random.default_rng(seed)
    v, f = grid(n_side, n_side, 2.0, lambda x, y: 0.05 * x * y)
    n = len(v)
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    x = (np.tile(np.eye(3, 4).ravel(), n) + 0.2 * rng.standard_normal(12 * n)).reshape(n, 12)
    targets = v + rng.normal(0, 1, v.shape)
    normals = rng.normal(0, 1, v.shape) + [0, 0, 3]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    weights = (rng.random(n) > 0.2).astype(float)
    aid = rng.choice(n, 4, replace=False).astype(np.int64)
    apts = v[aid] + rng.normal(0, 2, (4, 3))
    return x, v, edges, targets, normals, weights, aid, apts


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_energy_and_gradient_match_numpy_reference(seed):
    args = random_problem(seed)
    w = (1.3, 250.0, 7.5, 2.0)
    ours = _core.shape_fit_energy(*args, *w)
    ref = shape_energy(*args, *w)
    for a, b in zip(ours[:5], ref[:5]):
        assert a == pytest.approx(b, rel=1e-10, abs=1e-10)
    np.testing.assert_allclose(ours[5], ref[5], rtol=1e-10, atol=1e-9)


def test_gradient_matches_finite_differences():
    args = random_problem(5, n_side=4)
    w = (1.0, 20.0, 10.0, 3.0)
    x = args[0]
    g = _core.shape_fit_energy(*args, *w)[5].ravel()
    h = 1e-6
    fd = np.empty_like(g)
    for k in range(x.size):
        xp = x.copy().ravel(); xp[k] += h
        xm = x.copy().ravel(); xm[k] -= h
        ep = _core.shape_fit_energy(xp.reshape(x.shape), *args[1:], *w)[0]
        em = _core.shape_fit_energy(xm.reshape(x.shape), *args[1:], *w)[0]
        fd[k] = (ep - em) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-4)


def test_known_bend_is_recovered():
    """Template = scan up to a smooth isometric bend (rolled onto a 60 mm cylinder)."""
    surf = lambda x, y: 8.0 * np.exp(-((x - 30) ** 2 + (y - 32) ** 2) / 60.0) + 0.002 * (y - 30) ** 2
    radius = 60.0

    def roll(p):
        u, r = (p[:, 0] - 30.0) / radius, radius + p[:, 2]
        return np.stack([30 + r * np.sin(u), p[:, 1], r * np.cos(u) - radius + 1.0], axis=1)

    tv, tf = grid(21, 21, 3.0, surf)
    sv, sf = grid(61, 61, 1.0, surf)
    scan = Mesh(roll(sv), sf)
    aid = np.array([10 * 21 + 10, 5 * 21 + 5, 5 * 21 + 15, 15 * 21 + 5, 15 * 21 + 15])
    # the paper-literal schedule (12 levels, tolerances 1e-4 / 1e-3, memory 10)
    res = fit_shape(tv, tf, scan, anchors=(aid, roll(tv[aid])), w_landmark=1.0, n_levels=12, rel_tol=1e-4,
                    relax_tol=1e-3, memory=10)
    inner = (tv[:, 0] >= 6) & (tv[:, 0] <= 54) & (tv[:, 1] >= 6) & (tv[:, 1] <= 54)
    err = np.linalg.norm(res.vertices - roll(tv), axis=1)[inner]
    assert err.mean() < 1.0 and err.max() < 2.5, (err.mean(), err.max())
    # transforms reproduce the vertices
    ph = np.hstack([tv, np.ones((len(tv), 1))])
    np.testing.assert_allclose(np.einsum("nkc,nc->nk", res.transforms, ph), res.vertices, atol=1e-9)
    assert res.solves and all(s["n_valid"] > 0 for s in res.solves)


def test_identity_when_template_is_on_the_scan():
    v, f = grid(15, 15, 2.0, lambda x, y: 0.01 * (x - 14) ** 2 + 0.02 * (y - 14) ** 2)
    res = fit_shape(v, f, Mesh(v, f), n_levels=3)
    assert np.abs(res.vertices - v).max() < 1e-6


def test_bad_input_is_a_value_error():
    v, f = grid(4, 4, 1.0, lambda x, y: 0 * x)
    scan = Mesh(v, f)
    with pytest.raises(ValueError, match="template_faces holds index"):
        fit_shape(v, f + 100, scan)
    with pytest.raises(ValueError, match="NaN"):
        fit_shape(np.full_like(v, np.nan), f, scan)
    with pytest.raises(ValueError, match="anchor_ids"):
        fit_shape(v, f, scan, anchors=([99], [[0, 0, 0]]))
    with pytest.raises(ValueError, match="n_levels"):
        fit_shape(v, f, scan, n_levels=0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'w_smoth'"):
        fit_shape(v, f, scan, w_smoth=1.0)


def test_rust_defaults_agree_with_the_dataclass():
    # The dataclass is the source of truth (the binding has no defaults); Rust's Default mirrors it.
    assert _core.shape_fit_default_options() == asdict(ShapeFitOptions())


def test_binding_has_no_defaults():
    v, f = grid(4, 4, 1.0, lambda x, y: 0 * x)
    scan = Mesh(v, f)
    args = (v, f, scan.surface, np.zeros(0, np.int64), np.zeros((0, 3)))
    kw = dict(asdict(ShapeFitOptions()), template_weight=None)
    for name in kw:
        with pytest.raises(TypeError, match=name):
            _core.shape_fit(*args, **{k: x for k, x in kw.items() if k != name})
