"""Small parts of the landmark pipeline: Gaussian potentials, voxel subsampling, tables, k-means start."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

from facecorr.evaluation.landmarks import landmark_table, markdown
from facecorr.geometry.spatial import voxel_subsample
from facecorr.landmarks.gaussian import fit_gaussian, log_density, mahalanobis2
from facecorr.landmarks.paper.search import _two_side_init
from facecorr.names import LANDMARK_NAMES


def test_gaussian_fit_and_density_match_scipy():
    rng = np.random.default_rng(0)
    x = rng.multivariate_normal([1, 2, 3], [[4, 1, 0], [1, 3, 0.5], [0, 0.5, 2]], size=500)
    mu, cov = fit_gaussian(x, ridge=0.0)
    np.testing.assert_allclose(mu, x.mean(0))
    np.testing.assert_allclose(cov, np.cov(x.T, bias=True))
    q = rng.normal(size=(7, 4, 3))
    np.testing.assert_allclose(log_density(q, mu, cov), multivariate_normal(mu, cov).logpdf(q), rtol=1e-10)
    d = q - mu
    np.testing.assert_allclose(mahalanobis2(q, mu, cov), np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d))
    # floor and ridge keep a degenerate sample set usable
    _, c = fit_gaussian(np.zeros((5, 3)), floor=1.0)
    np.testing.assert_allclose(c, np.eye(3))
    with pytest.raises(ValueError, match="at least 2"):
        fit_gaussian(np.zeros((1, 3)))


def test_voxel_subsample_one_per_cell():
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 20, size=(5000, 3))
    ids = np.arange(0, 5000, 2)
    sub = voxel_subsample(pts, ids, 4.0)
    assert set(sub) <= set(ids)
    cells = np.floor(pts[sub] / 4.0)
    assert len(np.unique(cells, axis=0)) == len(sub)           # one per cell
    assert len(np.unique(np.floor(pts[ids] / 4.0), axis=0)) == len(sub)  # every occupied cell kept
    # the kept vertex is the one nearest its cell centre
    for v in sub[:20]:
        c = np.floor(pts[v] / 4.0)
        same = ids[(np.floor(pts[ids] / 4.0) == c).all(1)]
        off = np.linalg.norm(pts[same] - (c + 0.5) * 4.0, axis=1)
        assert v == same[np.argmin(off)]


def _voxel_subsample_reference(points, ids, spacing):
    """``voxel_subsample`` by a lexsort of (cell, distance to its centre): per cell the first."""
    ids = np.asarray(ids, dtype=np.int64)
    cell = np.floor(points[ids] / spacing)
    order = np.lexsort((np.linalg.norm(points[ids] - (cell + 0.5) * spacing, axis=1), *cell.T[::-1]))
    c = cell[order]
    return np.sort(ids[order[np.r_[True, np.any(c[1:] != c[:-1], axis=1)]]])


@settings(max_examples=150, deadline=None)
@given(st.integers(1, 400), st.sampled_from([0.25, 0.5, 1.0, 2.0]), st.integers(0, 2**31))
def test_voxel_subsample_is_the_lexsort_reference(n, spacing, seed):
    """The hashed grouping picks what the lexsort reference picks, ties (points on a lattice: equal
    distances to the cell centre, duplicates, -0.0) to the first of ``ids``."""
    rng = np.random.default_rng(seed)
    pts = rng.integers(-4, 4, size=(n, 3)).astype(float) * rng.choice([0.25, 0.5, 1.0])
    pts[rng.random(n) < 0.1] *= -0.0  # some -0.0 coordinates
    ids = rng.permutation(n)[: rng.integers(1, n + 1)]
    np.testing.assert_array_equal(voxel_subsample(pts, ids, spacing), _voxel_subsample_reference(pts, ids, spacing))


def test_two_side_init_splits_left_right():
    tip, sub = np.array([0.0, 0, 20]), np.array([0.0, -10, 5])
    rng = np.random.default_rng(2)
    left = rng.normal([15, -6, 5], 1.5, size=(30, 3))
    right = rng.normal([-15, -6, 5], 1.5, size=(30, 3))
    init = _two_side_init(np.vstack([left, right]), tip, sub)
    assert {np.sign(init[0, 0]), np.sign(init[1, 0])} == {-1.0, 1.0}


def test_landmark_table_counts_failures_as_misses():
    ok = {"ok": True, "errors": {n: 5.0 for n in LANDMARK_NAMES}, "timings_s": {"total": 1.0, "bp": 0.1}}
    far = {"ok": True, "errors": {n: 25.0 for n in LANDMARK_NAMES}, "timings_s": {"total": 2.0, "bp": 0.2}}
    bad = {"ok": False, "scan": "x.ply", "error": "LandmarkError: no face"}
    rows = [ok, far, bad, ok]
    t = landmark_table(rows)
    assert t[0]["mean"] == pytest.approx(35 / 3) and t[0]["max"] == 25.0
    assert t[0]["T10"] == 50.0 and t[0]["T20"] == 50.0 and t[0]["T30"] == 75.0
    md = markdown(t, rows)
    assert "failed: 1" in md and "x.ply" in md and "all 8 within 30 mm: 3" in md
