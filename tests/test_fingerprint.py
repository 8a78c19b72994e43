"""Finger Print descriptor vs analytic values and a numpy clipped-area reference."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr.geometry.descriptors import fingerprint
from facecorr.geometry.geodesic import GeodesicSolver
from ref_kernels import fingerprint_reference, grid_mesh, ict_face_mesh, sphere_mesh


def test_plane_fingerprint_is_one_up_to_interpolation():
    # FMM is exact on the plane; the disk of the linearly interpolated distance is inscribed in
    # the true disk (the cone is convex), so FP <= 1 with a deficit O((h/r)^2) (0.17 (h/r)^2
    # measured on this grid)
    h = 0.25
    V, F = grid_mesh(80, 80, h)
    c = 40 * 81 + 40
    r = np.array([2.0, 4.0, 6.0, 8.0, 10.0])
    fp = fingerprint(V, F, [c], r)[0]
    assert (fp <= 1.0 + 1e-12).all()
    assert (1.0 - fp <= 0.2 * (h / r) ** 2).all(), 1 - fp


def test_sphere_fingerprint_analytic():
    R = 50.0
    V, F = sphere_mesh(6, R)  # 40962 vertices, edges about 1.2 mm
    r = np.array([5.0, 10.0, 15.0, 20.0, 25.0])
    analytic = 2 * R**2 * (1 - np.cos(r / R)) / r**2
    centers = np.arange(0, len(V), len(V) // 25)
    fp = fingerprint(V, F, centers, r)
    rel = np.abs(fp / analytic - 1)
    # measured max 0.0053 at r = 5 mm, < 0.0012 for r >= 10 mm; issue target 1%
    assert rel.max() <= 0.01, rel.max(axis=0)


def test_matches_numpy_clipped_area_reference():
    V, F = ict_face_mesh()
    s = GeodesicSolver(V, F)
    centers = np.array([0, 1000, 2500, 4000, 6000])
    radii = np.array([25.0, 3.0, 12.5, 7.0])  # unsorted on purpose
    fp = s.fingerprint(centers, radii)
    # the truncated propagation gives the same vertex distances as a full one, so the numpy
    # area of the clipped triangles over full FMM rows must agree to rounding
    ref = fingerprint_reference(V, F, s.distance_matrix(centers), radii)
    np.testing.assert_allclose(fp, ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(fp, fingerprint(V, F, centers, radii))


def test_boundary_centre_sees_part_of_the_disk():
    V, F = grid_mesh(40, 40, 0.5)
    fp = fingerprint(V, F, [0, 20], [5.0])  # corner and mid-edge vertices
    assert abs(fp[0, 0] - 0.25) < 0.01 and abs(fp[1, 0] - 0.5) < 0.01


@pytest.mark.parametrize(
    "centers, radii, msg",
    [
        ([0], [], "radii"),
        ([0], [0.0], "radii"),
        ([0], [np.nan], "radii"),
        ([0], [-1.0], "radii"),
        ([99], [1.0], "out of range"),
        ([0.5], [1.0], "integer"),
    ],
)
def test_bad_input(centers, radii, msg):
    V, F = grid_mesh(3, 3, 1.0)
    with pytest.raises(ValueError, match=msg) as e:
        fingerprint(V, F, centers, radii)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match=msg):
        GeodesicSolver(V, F).fingerprint(centers, radii)


def test_bad_mesh():
    V, F = grid_mesh(3, 3, 1.0)
    V[0, 0] = np.inf
    with pytest.raises(ValueError, match="NaN or inf"):
        fingerprint(V, F, [0], [1.0])


_face = {}


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_property_rigid_motion_and_renumbering(seed):
    if not _face:
        _face["m"] = ict_face_mesh()
    V, F = _face["m"]
    rng = np.random.default_rng(seed)
    centers = rng.choice(len(V), 5, replace=False)
    radii = np.array([4.0, 10.0, 20.0])
    fp = fingerprint(V, F, centers, radii)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    perm = rng.permutation(len(V))
    inv = np.argsort(perm)
    V2 = (V @ Q.T + rng.normal(size=3) * 50)[perm]
    fp2 = fingerprint(V2, inv[F], inv[centers], radii)
    np.testing.assert_allclose(fp2, fp, rtol=1e-9)
