"""Model file: round trip, size, validation with one-line ModelError messages."""

import json

import numpy as np
import pytest

from facecorr.errors import ModelError
from facecorr.landmarks.paper.classify import fit_classifier
from facecorr.landmarks.model import FORMAT_VERSION, LandmarkModel, load_model


def make_model(seed=0, s=7):
    rng = np.random.default_rng(seed)
    fp = np.concatenate([rng.normal(size=s) + 0.05 * rng.normal(size=(30, s)) for _ in range(8)])
    labels = np.repeat(np.arange(8), 30)
    clf = fit_classifier(fp, labels, 8)
    a = rng.normal(size=(8, s, s))
    edges = np.array([[0, 1], [1, 2], [2, 3], [4, 6], [5, 6], [6, 7]])
    b = rng.normal(size=(len(edges), 3, 3))
    return LandmarkModel(
        radii=np.linspace(5, 35, s), classifier=clf, node_mean=rng.normal(size=(8, s)),
        node_cov=a @ a.transpose(0, 2, 1) + np.eye(s), edges=edges, edge_mean=rng.normal(size=(len(edges), 3)),
        edge_cov=b @ b.transpose(0, 2, 1) + np.eye(3), graph_points=rng.normal(size=(8, 3)) * 30,
        search_radius=np.full(8, 12.0), nose_pair_mean=np.full((4, 4), 20.0) - 20 * np.eye(4),
        nose_pair_std=np.full((4, 4), 3.0), icp_points=rng.normal(size=(50, 3)) * 30,
        icp_tip_normal=np.array([0.0, 0, 1]), offset_mean=np.zeros((8, 3)), offset_cov=np.tile(4 * np.eye(3), (8, 1, 1)),
        params={"nose_search_radius_mm": 25.0, "trained_on": "test"})


def test_round_trip(tmp_path):
    m = make_model()
    p = tmp_path / "m.npz"
    m.save(p)
    assert p.stat().st_size < 5_000_000
    m2 = load_model(p)
    for k in ("radii", "node_mean", "node_cov", "edges", "edge_mean", "edge_cov", "graph_points", "search_radius"):
        np.testing.assert_array_equal(getattr(m2, k), getattr(m, k))
    np.testing.assert_array_equal(m2.classifier.ellipse_A, m.classifier.ellipse_A)
    assert m2.params == m.params and m2.param("mds_samples") > 0


def _corrupt(tmp_path, **changes):
    m = make_model()
    p = tmp_path / "good.npz"
    m.save(p)
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            del arrays[k]
        else:
            arrays[k] = v
    q = tmp_path / "bad.npz"
    np.savez(q, **arrays)
    return q


@pytest.mark.parametrize("changes,match", [
    ({"node_cov": None}, "missing 'node_cov'"),
    ({"format_version": np.int64(FORMAT_VERSION + 1)}, "format version"),
    ({"radii": np.linspace(5, 35, 6)}, "inconsistent with S"),
    ({"edges": np.array([[0, 1], [1, 9]])}, "inconsistent with E|edges"),
    ({"edge_mean": np.full((6, 3), np.nan)}, "NaN"),
    ({"edge_cov": -np.tile(np.eye(3), (6, 1, 1))}, "positive definite"),
    ({"params": np.array("[1, 2]")}, "JSON object"),
    ({"landmark_names": np.array(["a"] * 8)}, "landmark names"),
    ({"nose_pair_std": np.zeros((4, 4))}, "nose_pair_std"),
])
def test_validation_errors(tmp_path, changes, match):
    with pytest.raises(ModelError, match=match) as e:
        load_model(_corrupt(tmp_path, **changes))
    assert "\n" not in str(e.value)


def test_missing_and_garbage_files(tmp_path):
    with pytest.raises(ModelError, match="no such model"):
        load_model(tmp_path / "nope.npz")
    g = tmp_path / "garbage.npz"
    g.write_bytes(b"not a zip")
    with pytest.raises(ModelError, match="not a readable"):
        load_model(g)
    assert json.loads(json.dumps(make_model().params))
