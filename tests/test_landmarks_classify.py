"""FPPCA classifier: PCA, medoids, M-clusters and ellipsoid rules on synthetic FP data."""

import numpy as np
import pytest

from facecorr.landmarks.paper.classify import fit_classifier, medoid


def _data(seed=0, n=60, s=10, classes=4):
    rng = np.random.default_rng(seed)
    centers = rng.normal(size=(classes, s)) * 0.5 + 1.0
    fp = np.concatenate([c + 0.03 * rng.normal(size=(n, s)) for c in centers])
    labels = np.repeat(np.arange(classes), n)
    return fp, labels, centers


def test_medoid_brute_force():
    p = np.random.default_rng(0).normal(size=(30, 3))
    best = min(range(30), key=lambda i: np.linalg.norm(p - p[i], axis=1).sum())
    assert medoid(p) == best


def test_classifier_separates_and_contains_m_cluster():
    fp, labels, centers = _data()
    clf = fit_classifier(fp, labels, 4)
    assert clf.components.shape == (3, 10)
    np.testing.assert_allclose(clf.components @ clf.components.T, np.eye(3), atol=1e-10)
    lab = clf.label(fp)
    for c in range(4):
        proj = clf.project(fp[labels == c])
        dist = np.linalg.norm(proj - clf.medoids[c], axis=1)
        inside = dist <= 1.5 * clf.sigma[c]
        # every M-cluster sample satisfies its rule; the M-cluster is most but not all samples
        assert lab[labels == c][inside, c].all()
        assert 0.6 < inside.mean() < 1.0
        # well separated synthetic classes: no sample of another class gets label c
        assert not lab[labels != c, c].any()
    # nearest medoid = true class
    np.testing.assert_array_equal(np.argmin(clf.medoid_distance(fp), axis=1), labels)
    # a far-away descriptor gets no label
    assert not clf.label(np.full((1, 10), 10.0)).any()


def test_degenerate_cluster_is_regularised():
    fp, labels, _ = _data(n=3)  # 3 samples per class in 3-D PCA space: flat M-clusters
    clf = fit_classifier(fp, labels, 4)
    assert np.isfinite(clf.ellipse_A).all()
    assert clf.label(fp)[np.arange(len(fp)), labels].sum() >= len(fp) - 4  # at most the outliers


def test_bad_input():
    fp, labels, _ = _data()
    with pytest.raises(ValueError, match="class 4 has no"):
        fit_classifier(fp, labels, 6)
    with pytest.raises(ValueError, match="disagree"):
        fit_classifier(fp, labels[:-1], 4)
    clf = fit_classifier(fp, labels, 4)
    with pytest.raises(ValueError, match="10 radii"):
        clf.label(np.zeros((2, 9)))
