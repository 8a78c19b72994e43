"""Kabsch and the D_F flip decision of the landmark-graph alignment."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from facecorr.geometry.transforms import kabsch
from facecorr.landmarks.paper.alignment import align_graph

# A plausible landmark graph Pa (template frame: +y up, +z out, subject's right at -x), mm.
PA = np.array([
    [-45.0, 35.0, -5.0],   # right outer eye corner
    [-15.0, 33.0, 2.0],    # right inner eye corner
    [15.0, 33.0, 2.0],     # left inner eye corner
    [45.0, 35.0, -5.0],    # left outer eye corner
    [-16.0, -5.0, 10.0],   # right subalare
    [16.0, -5.0, 10.0],    # left subalare
    [0.0, 0.0, 30.0],      # nose tip
    [0.0, -10.0, 15.0],    # subnasal
])


def _face_surface(pa, n=6000, seed=0):
    """A rough face-like point set containing Pa's region: a spherical cap plus the points."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-1.2, 1.2, n)
    phi = rng.uniform(-1.0, 1.0, n)
    r = 80.0
    cap = np.column_stack([r * np.sin(theta) * np.cos(phi), r * np.sin(phi), r * np.cos(theta) * np.cos(phi) - 75])
    return np.vstack([cap, pa])


@pytest.mark.parametrize("seed", range(10))
def test_kabsch_recovers_rigid_transform(seed):
    rng = np.random.default_rng(seed)
    r = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3) * 50
    x = rng.normal(size=(10, 3)) * 20
    r2, t2 = kabsch(x, x @ r.T + t)
    np.testing.assert_allclose(r2, r, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-8)
    assert np.linalg.det(r2) == pytest.approx(1.0)


def test_kabsch_reflection_only_when_allowed():
    x = np.random.default_rng(1).normal(size=(10, 3))
    mirrored = x * [-1, 1, 1]
    r, _ = kabsch(x, mirrored)
    assert np.linalg.det(r) == pytest.approx(1.0)
    r, t = kabsch(x, mirrored, allow_reflection=True)
    np.testing.assert_allclose(x @ r.T + t, mirrored, atol=1e-10)


@pytest.mark.parametrize("seed", range(8))
def test_flip_picks_right_configuration(seed):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    shift = rng.normal(size=3) * 100
    surface = _face_surface(PA, seed=seed) @ rot.T + shift
    truth = PA @ rot.T + shift + rng.normal(size=(8, 3)) * 1.0  # found points with 1 mm noise
    tree = cKDTree(surface)
    # Correct order (right, left) ...
    al = align_graph(PA, truth[[4, 5, 6, 7]], tree)
    assert not al.flipped
    assert np.linalg.norm(al.points - PA @ rot.T - shift, axis=1).max() < 8  # 1 mm noise on a 30 mm base, 50 mm lever
    # ... and the mirrored input (left subalare given first): must detect the swap.
    al = align_graph(PA, truth[[5, 4, 6, 7]], tree)
    assert al.flipped
    assert al.d_f[1] < al.d_f[0]
    assert np.linalg.norm(al.points - PA @ rot.T - shift, axis=1).max() < 8  # 1 mm noise on a 30 mm base, 50 mm lever


def test_mirrored_face_gets_mirrored_labels():
    # A mirror image of a face (x -> -x): what was the right subalare is now on the left side, so
    # the configuration that matches the surface is the swapped one.
    mirror = np.diag([-1.0, 1.0, 1.0])
    surface = _face_surface(PA) @ mirror
    found = (PA @ mirror)[[4, 5, 6, 7]]
    al = align_graph(PA, found, cKDTree(surface))
    assert al.flipped
    np.testing.assert_allclose(al.points[[4, 5]], found[[1, 0]], atol=1e-6)


def test_bad_shapes():
    with pytest.raises(ValueError, match="nose_points"):
        align_graph(PA, PA[:3], cKDTree(PA))
