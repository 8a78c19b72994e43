"""Rust mesh utilities (facecorr.mesh.Mesh) vs the numpy references in ref_mesh.py."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import ref_mesh as R
from facecorr import _core
from facecorr.errors import MeshError
from facecorr.geometry.mesh import Mesh


def random_mesh(rng, n=60, m=120, n_pieces=1):
    """Random triangle soup-like mesh with shared vertices (several pieces when asked)."""
    V, F = [], []
    for p in range(n_pieces):
        off = len(V) if p else 0
        V += list(rng.normal(size=(n, 3)) * 10 + p * 100)
        F += list(rng.integers(0, n, size=(m, 3)) + off)
    F = np.array(F)
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    return np.array(V), F


def check_against_reference(V, F):
    m = Mesh(V, F)
    np.testing.assert_allclose(m.face_areas, R.face_areas(V, F), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(m.vertex_areas, R.vertex_areas(V, F), rtol=1e-12, atol=1e-12)
    # Normals: where opposite faces cancel (|sum| ~ rounding), the direction is arbitrary in both
    # implementations; compare where the area-weighted sum is well above rounding.
    fn = R.face_normals_unnormalized(V, F)
    raw, mag = np.zeros_like(V), np.zeros(len(V))
    for k in range(3):
        np.add.at(raw, F[:, k], fn)
        np.add.at(mag, F[:, k], np.linalg.norm(fn, axis=1))
    ok = np.linalg.norm(raw, axis=1) > 1e-6 * mag
    np.testing.assert_allclose(m.vertex_normals[ok], R.vertex_normals(V, F)[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(m.vertex_normals[mag > 0], axis=1)[ok[mag > 0]], 1, atol=1e-12)
    np.testing.assert_array_equal(m.edges, R.edges(F))
    np.testing.assert_array_equal(m.boundary_vertices, R.boundary_vertices(F))
    # Same partition, same area ranking (areas of distinct pieces differ in these meshes).
    np.testing.assert_array_equal(m.components, R.components(V, F))
    assert m.edges.dtype == np.int64 and m.components.dtype == np.int64


def test_sphere_against_reference():
    V, F = R.sphere(10.0, 3)
    check_against_reference(V, F)
    m = Mesh(V, F)
    assert len(m.boundary_vertices) == 0 and m.n_components == 1
    # outward unit normals on a sphere
    assert np.all(np.einsum("ij,ij->i", m.vertex_normals, V / 10.0) > 0.999)
    np.testing.assert_allclose(m.vertex_areas.sum(), m.face_areas.sum(), rtol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_random_meshes_against_reference(seed):
    rng = np.random.default_rng(seed)
    V, F = random_mesh(rng, n_pieces=1 + seed % 3)
    check_against_reference(V, F)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(4, 40), st.integers(1, 80))
def test_property_random(seed, n, m):
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(n, 3))
    F = rng.integers(0, n, size=(m, 3))
    check_against_reference(V, F)


def test_components_order_and_isolated_vertices():
    # big square, small triangle, and an isolated vertex
    V = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0],
                  [20, 0, 0], [21, 0, 0], [20, 1, 0], [50, 50, 50]], float)
    F = np.array([[4, 5, 6], [0, 1, 2], [0, 2, 3]])
    m = Mesh(V, F)
    np.testing.assert_array_equal(m.components, [0, 0, 0, 0, 1, 1, 1, 2])
    np.testing.assert_array_equal(m.components, R.components(V, F))
    np.testing.assert_array_equal(m.vertex_normals[7], [0, 0, 0])


def test_submesh_and_largest_component():
    V = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0],
                  [20, 0, 0], [21, 0, 0], [20, 1, 0]], float)
    F = np.array([[4, 5, 6], [0, 1, 2], [0, 2, 3]])
    m = Mesh(V, F, to_mm=10.0, units="cm", source="x.ply", meta={"a": 1})
    big, old = m.largest_component()
    np.testing.assert_array_equal(old, [0, 1, 2, 3])
    np.testing.assert_array_equal(big.vertices, V[:4])
    np.testing.assert_array_equal(old[big.faces], F[1:])
    assert big.to_mm == 10.0 and big.units == "cm" and big.meta == {"a": 1}
    # integer ids work the same as a mask; faces with an unselected vertex are dropped
    sub, old = m.submesh(np.array([0, 2, 3, 4]))
    np.testing.assert_array_equal(old, [0, 2, 3, 4])
    np.testing.assert_array_equal(old[sub.faces], [[0, 2, 3]])
    with pytest.raises(MeshError, match="no triangle"):
        m.submesh(np.array([0, 1, 4]))
    with pytest.raises(MeshError, match="shape"):
        m.submesh(np.ones(3, bool))
    with pytest.raises(MeshError, match="out of range"):
        m.submesh(np.array([0, 99]))


def test_binding_validation_is_one_line_value_error():
    V, F = R.sphere(1.0, 1)
    bad = V.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="vertex 3 has a NaN"):
        _core.mesh_vertex_normals(bad, F)
    with pytest.raises(ValueError, match="outside"):
        _core.mesh_face_areas(V, F + len(V))
    with pytest.raises(ValueError, match="outside"):
        _core.mesh_edges(-F, len(V))
    with pytest.raises(ValueError, match="shape"):
        _core.mesh_vertex_areas(V[:, :2].copy(), F)
    with pytest.raises(ValueError, match="no faces"):
        _core.mesh_components(V, np.zeros((0, 3), np.int64))


def test_large_mesh_is_consistent():
    """A 40k-vertex sphere: Rust and numpy agree (also exercises the parallel paths)."""
    V, F = R.sphere(50.0, 6)
    check_against_reference(V, F)


def test_kdtree_is_built_once_and_correct(monkeypatch):
    import facecorr.geometry.spatial as spatial

    V, F = R.sphere(10.0, 2)
    m = Mesh(V, F)
    built = []
    real = spatial.KDTree
    monkeypatch.setattr(spatial, "KDTree", lambda pts: built.append(len(pts)) or real(pts))
    m.kdtree, m.kdtree
    assert built == [len(V)]  # one tree for every stage that asks
    d, i = m.kdtree.query(V[[5, 7]] + 1e-6)
    np.testing.assert_array_equal(i, [5, 7])


def _grid_with_hole(n=12, hole=(4, 7)):
    """(V, F) of an n x n vertex grid (1 mm) without the cells of the square ``hole`` (cell range)."""
    V = np.array([[i, j, 0.0] for j in range(n) for i in range(n)])
    F = []
    for j in range(n - 1):
        for i in range(n - 1):
            if hole[0] <= i < hole[1] and hole[0] <= j < hole[1]:
                continue
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F)


def test_outer_boundary_is_the_border_not_the_hole():
    n = 12
    V, F = _grid_with_hole(n)
    m = Mesh(V, F)
    ij = V[:, :2].astype(int)
    border = np.flatnonzero((ij == 0).any(axis=1) | (ij == n - 1).any(axis=1))
    np.testing.assert_array_equal(m.outer_boundary, border)
    # the hole's rim is a boundary too, but a shorter curve
    rim = np.setdiff1d(m.boundary_vertices, border)
    assert len(rim) == 12 and not np.isin(rim, m.outer_boundary).any()


def test_outer_boundary_of_a_closed_mesh_is_empty():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert Mesh(V, F).outer_boundary.shape == (0,)


@settings(max_examples=25, deadline=None)
@given(st.integers(4, 14), st.integers(1, 3), st.integers(1, 4))
def test_outer_boundary_property_grid(n, lo, size):
    # any grid with an interior hole: the outer boundary is the grid's perimeter
    hi = min(lo + size, n - 2)
    if hi <= lo:
        return
    V, F = _grid_with_hole(n, (lo, hi))
    ij = V[:, :2].astype(int)
    border = np.flatnonzero((ij == 0).any(axis=1) | (ij == n - 1).any(axis=1))
    np.testing.assert_array_equal(Mesh(V, F).outer_boundary, border)
