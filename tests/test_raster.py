"""facecorr.raster (compiled z-buffer) against a numpy brute-force reference."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from facecorr.raster import rasterize


def raster_reference(uv, depth, tris, W, H):
    """Brute force: every triangle against every pixel centre, the same edge functions and tie rule."""
    tri = np.full((H, W), -1, np.int32)
    bary = np.zeros((H, W, 3))
    z = np.full((H, W), np.inf)
    py, px = np.mgrid[0:H, 0:W].astype(float)
    for ti, (i, j, k) in enumerate(tris):
        a, b, c = uv[i], uv[j], uv[k]
        area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if area == 0:
            continue
        w0 = (c[0] - b[0]) * (py - b[1]) - (c[1] - b[1]) * (px - b[0])
        w1 = (a[0] - c[0]) * (py - c[1]) - (a[1] - c[1]) * (px - c[0])
        w2 = (b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0])
        l0, l1, l2 = w0 / area, w1 / area, w2 / area
        inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        zz = l0 * depth[i] + l1 * depth[j] + l2 * depth[k]
        win = inside & ((zz < z) | ((zz == z) & (ti < tri)))
        tri[win], z[win] = ti, zz[win]
        bary[win] = np.stack([l0, l1, l2], -1)[win]
    return tri, bary, z


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 40), st.integers(3, 37), st.integers(3, 29))
def test_random_triangles_match_brute_force(seed, m, W, H):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-5, [W + 5, H + 5], size=(3 * m, 2))
    depth = rng.uniform(0, 10, 3 * m)
    tris = np.arange(3 * m).reshape(m, 3)
    got = rasterize(uv, depth, tris, W, H)
    ref = raster_reference(uv, depth, tris, W, H)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got[2], ref[2])


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
    ref = raster_reference(uv, depth, tris, 28, 28)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_allclose(got[2], ref[2], atol=1e-12)
    # pixels well inside the mesh are all covered (shared edges leave no cracks)
    assert (got[0][3:24, 3:24] >= 0).all()


def test_barycentric_reconstructs_pixel_centre():
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 50, (60, 2))
    tris = rng.integers(0, 60, (20, 3))
    tri, bary, _ = rasterize(uv, rng.uniform(0, 1, 60), tris, 50, 50)
    r, c = np.nonzero(tri >= 0)
    p = np.einsum("sk,skd->sd", bary[r, c], uv[tris[tri[r, c]]])
    np.testing.assert_allclose(p, np.stack([c, r], 1), atol=1e-8)


def test_bad_input_is_a_value_error():
    uv = np.zeros((3, 2))
    with pytest.raises(ValueError, match="triangle indices"):
        rasterize(uv, np.zeros(3), np.array([[0, 1, 5]]), 4, 4)
    with pytest.raises(ValueError, match="finite"):
        rasterize(np.full((3, 2), np.nan), np.zeros(3), np.array([[0, 1, 2]]), 4, 4)
    with pytest.raises(ValueError, match="depth"):
        rasterize(uv, np.zeros(2), np.array([[0, 1, 2]]), 4, 4)
    with pytest.raises(ValueError, match="image size"):
        rasterize(uv, np.zeros(3), np.array([[0, 1, 2]]), 0, 4)
