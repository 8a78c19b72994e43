"""facecorr.raster.rasterize (Rust z-buffer) against a brute-force numpy reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facecorr.geometry.raster import rasterize


def rasterize_reference(uv, depth, tris, width, height):
    """Every pixel centre against every triangle: same edge functions as the kernel, nearest
    depth wins, exact ties to the smaller triangle id, zero-area triangles cover nothing."""
    tri_img = np.full((height, width), -1, dtype=np.int64)
    bary_img = np.zeros((height, width, 3))
    z_img = np.full((height, width), np.inf)
    py, px = np.meshgrid(np.arange(height, dtype=float), np.arange(width, dtype=float), indexing="ij")
    for ti, (i, j, k) in enumerate(tris):
        a, b, c = uv[i], uv[j], uv[k]
        area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if area == 0.0:
            continue
        w0 = (c[0] - b[0]) * (py - b[1]) - (c[1] - b[1]) * (px - b[0])
        w1 = (a[0] - c[0]) * (py - c[1]) - (a[1] - c[1]) * (px - c[0])
        w2 = (b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0])
        l0, l1, l2 = w0 / area, w1 / area, w2 / area
        z = l0 * depth[i] + l1 * depth[j] + l2 * depth[k]
        win = (l0 >= 0) & (l1 >= 0) & (l2 >= 0) & (z < z_img)  # ids ascend: a tie keeps the smaller
        tri_img[win] = ti
        z_img[win] = z[win]
        bary_img[win] = np.stack([l0, l1, l2], -1)[win]
    return tri_img, bary_img, z_img


def _random_scene(rng, n_tri, width, height):
    uv = rng.uniform([-3, -3], [width + 2, height + 2], size=(3 * n_tri, 2))
    depth = rng.uniform(0.0, 10.0, size=3 * n_tri)
    tris = np.arange(3 * n_tri).reshape(n_tri, 3)
    return uv, depth, tris


@pytest.mark.parametrize("seed", range(6))
def test_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    width, height = 23 + seed, 17 + 2 * seed
    uv, depth, tris = _random_scene(rng, 12 + 4 * seed, width, height)
    tri, bary, z = rasterize(uv, depth, tris, width, height)
    rt, rb, rz = rasterize_reference(uv, depth, tris, width, height)
    assert tri.shape == (height, width) and bary.shape == (height, width, 3)
    assert (tri >= 0).sum() > 0.3 * tri.size  # the scenes are not trivially empty
    np.testing.assert_array_equal(tri, rt)
    np.testing.assert_allclose(bary, rb, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.isinf(z), np.isinf(rz))
    hit = tri >= 0
    np.testing.assert_allclose(z[hit], rz[hit], rtol=0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.integers(1, 20), st.integers(1, 20))
def test_properties(seed, n_tri, width, height):
    """Hit pixels: barycentrics sum to 1, are >= 0, reproduce the pixel centre and the depth."""
    rng = np.random.default_rng(seed)
    uv, depth, tris = _random_scene(rng, n_tri, width, height)
    tri, bary, z = rasterize(uv, depth, tris, width, height)
    rt, _, _ = rasterize_reference(uv, depth, tris, width, height)
    np.testing.assert_array_equal(tri, rt)
    rows, cols = np.nonzero(tri >= 0)
    b = bary[rows, cols]
    t = tris[tri[rows, cols]]
    assert (b >= 0).all()
    np.testing.assert_allclose(b.sum(1), 1.0, atol=1e-9)
    centre = np.einsum("sk,skd->sd", b, uv[t])
    np.testing.assert_allclose(centre, np.stack([cols, rows], 1), atol=1e-7)
    np.testing.assert_allclose(z[rows, cols], np.einsum("sk,sk->s", b, depth[t]), atol=1e-9)
    assert (bary[tri < 0] == 0).all() and np.isinf(z[tri < 0]).all()


def test_connected_mesh_matches_brute_force_and_has_no_gaps():
    # a 2.5-D height field: a regular grid of quads jittered, covering the image fully
    rng = np.random.default_rng(3)
    n = 9
    gy, gx = np.mgrid[0:n, 0:n].astype(float)
    uv = np.stack([gx.ravel() * 4 - 1, gy.ravel() * 4 - 1], 1) + rng.uniform(-0.7, 0.7, (n * n, 2)) * (gx.ravel()[:, None] % (n - 1) > 0)
    depth = rng.uniform(0, 1, n * n)
    ids = np.arange(n * n).reshape(n, n)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[:-1, 1:].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
    got = rasterize(uv, depth, tris, 28, 28)
    ref = rasterize_reference(uv, depth, tris, 28, 28)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_allclose(got[2], ref[2], atol=1e-12)
    # pixels well inside the mesh are all covered (shared edges leave no cracks)
    assert (got[0][3:24, 3:24] >= 0).all()


def test_nearest_wins_regardless_of_order():
    uv = np.array([[0, 0], [10, 0], [0, 10]] * 2, dtype=float)
    for near_first in (True, False):
        depth = np.array([1.0] * 3 + [2.0] * 3) if near_first else np.array([2.0] * 3 + [1.0] * 3)
        tri, _, z = rasterize(uv, depth, np.array([[0, 1, 2], [3, 4, 5]]), 12, 12)
        assert tri[2, 2] == (0 if near_first else 1)
        assert z[2, 2] == 1.0
    # exact tie: the smaller id, whatever the order
    tri, _, _ = rasterize(uv, np.ones(6), np.array([[3, 4, 5], [0, 1, 2]]), 12, 12)
    assert tri[2, 2] == 0


def test_pixel_on_edge_is_covered_and_outside_is_not():
    uv = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    tri, bary, _ = rasterize(uv, np.zeros(3), np.array([[0, 1, 2]]), 6, 6)
    assert tri[0, 0] == 0 and tri[0, 4] == 0 and tri[2, 2] == 0  # vertex, vertex, hypotenuse
    assert tri[3, 2] == -1 and tri[5, 5] == -1
    np.testing.assert_allclose(bary[0, 4], [0, 1, 0], atol=1e-15)


def test_empty_and_degenerate_cover_nothing():
    tri, bary, z = rasterize(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 3), dtype=np.int64), 5, 4)
    assert (tri == -1).all() and np.isinf(z).all() and (bary == 0).all()
    uv = np.array([[0.0, 0.0], [2.0, 2.0], [4.0, 4.0], [1.0, 1.0]])  # collinear; a repeated vertex
    tri, _, _ = rasterize(uv, np.zeros(4), np.array([[0, 1, 2], [3, 3, 1]]), 6, 6)
    assert (tri == -1).all()


@pytest.mark.parametrize(
    "uv, depth, tris, w, h, match",
    [
        (np.zeros((3, 3)), np.zeros(3), [[0, 1, 2]], 4, 4, "uv"),
        (np.zeros((3, 2)), np.zeros(2), [[0, 1, 2]], 4, 4, "depth"),
        (np.zeros((3, 2)), np.zeros(3), [[0, 1]], 4, 4, "triangles"),
        (np.zeros((3, 2)), np.zeros(3), [[0, 1, 3]], 4, 4, "indices"),
        (np.zeros((3, 2)), np.zeros(3), [[0, 1, -1]], 4, 4, "indices"),
        (np.array([[0, 0], [1, np.nan], [0, 1.0]]), np.zeros(3), [[0, 1, 2]], 4, 4, "finite"),
        (np.zeros((3, 2)), np.array([0, np.inf, 0]), [[0, 1, 2]], 4, 4, "finite"),
        (np.zeros((3, 2)), np.zeros(3), [[0, 1, 2]], 0, 4, "image size"),
    ],
)
def test_bad_input_one_line_value_error(uv, depth, tris, w, h, match):
    with pytest.raises(ValueError, match=match) as ei:
        rasterize(uv, depth, np.asarray(tris), w, h)
    assert "\n" not in str(ei.value)
