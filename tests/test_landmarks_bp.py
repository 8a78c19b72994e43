"""Loopy max-product BP against exhaustive enumeration."""

import numpy as np
import pytest

from facecorr.landmarks.paper.bp import brute_force_map, joint_score, max_product


def _random_network(rng, edges, n, kmax=4):
    ks = rng.integers(2, kmax + 1, size=n)
    unary = [rng.normal(size=k) for k in ks]
    pairwise = {(i, j): 1.5 * rng.normal(size=(ks[i], ks[j])) for i, j in edges}
    return unary, pairwise


TREE = [(0, 1), (1, 2), (1, 3), (3, 4), (3, 5), (0, 6)]


@pytest.mark.parametrize("seed", range(25))
def test_tree_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    unary, pairwise = _random_network(rng, TREE, 7)
    ref_labels, ref_score = brute_force_map(unary, pairwise)
    res = max_product(unary, pairwise)
    assert res.converged
    assert res.score == pytest.approx(ref_score, abs=1e-9)
    np.testing.assert_array_equal(res.labels, ref_labels)  # continuous random potentials: unique MAP


def test_tree_max_marginals_exact():
    rng = np.random.default_rng(7)
    unary, pairwise = _random_network(rng, TREE, 7, kmax=3)
    res = max_product(unary, pairwise)
    import itertools
    for i in range(7):
        mm = np.full(len(unary[i]), -np.inf)
        for labels in itertools.product(*[range(len(u)) for u in unary]):
            mm[labels[i]] = max(mm[labels[i]], joint_score(labels, unary, pairwise))
        # beliefs are max-marginals up to an additive constant
        np.testing.assert_allclose(res.beliefs[i] - res.beliefs[i].max(), mm - mm.max(), atol=1e-9)


# The paper's landmark graph shape: a loopy graph over 8 nodes.
LOOPY = [(0, 1), (1, 2), (2, 3), (1, 7), (2, 7), (4, 6), (5, 6), (4, 7), (5, 7), (6, 7), (0, 4), (3, 5)]


def test_loopy_near_optimal():
    # Loopy max-product + ICM is not guaranteed optimal; on small random loopy networks it must
    # find the exact MAP in most cases, never exceed it, and stay close otherwise.
    gaps = []
    for seed in range(15):
        rng = np.random.default_rng(100 + seed)
        unary, pairwise = _random_network(rng, LOOPY, 8, kmax=3)
        _, ref_score = brute_force_map(unary, pairwise)
        res = max_product(unary, pairwise, max_iter=200)
        gaps.append(ref_score - res.score)
    gaps = np.array(gaps)
    assert (gaps >= -1e-9).all()
    assert (gaps < 1e-9).sum() >= 12, gaps  # measured: 14 of 15 exact
    assert gaps.max() < 1.0, gaps


def test_loopy_recovers_planted_assignment():
    # Strong unaries pointing at a planted truth plus agreeing pairwise terms: BP must find it.
    rng = np.random.default_rng(3)
    truth = rng.integers(0, 5, size=8)
    unary = [np.where(np.arange(5) == truth[i], 0.0, -1.0) + 0.3 * rng.normal(size=5) for i in range(8)]
    pairwise = {}
    for i, j in LOOPY:
        p = -2.0 * np.ones((5, 5)) + 0.3 * rng.normal(size=(5, 5))
        p[truth[i], truth[j]] = 0.0
        pairwise[(i, j)] = p
    res = max_product(unary, pairwise)
    np.testing.assert_array_equal(res.labels, truth)
    assert (res.confidence > 0.5).all()


def test_forbidden_labels_and_errors():
    unary = [np.array([0.0, -np.inf]), np.array([-1.0, 0.0])]
    pairwise = {(0, 1): np.array([[0.0, -5.0], [3.0, 3.0]])}
    res = max_product(unary, pairwise)
    assert res.labels.tolist() == [0, 0]
    with pytest.raises(ValueError, match="shape"):
        max_product(unary, {(0, 1): np.zeros((3, 2))})
    with pytest.raises(ValueError, match="NaN"):
        max_product([np.array([np.nan])], {})
    with pytest.raises(ValueError, match="bad edge"):
        max_product(unary, {(0, 0): np.zeros((2, 2))})
