//! Z-buffer rasterization of triangles given in image coordinates.
//!
//! The caller projects the vertices itself (perspective camera, cylinder around the head, ...)
//! and passes per-vertex image coordinates `(u, v)` in pixel units plus a per-vertex depth. Pixel
//! `(row, col)` has its centre at `u = col`, `v = row`. A pixel is covered by a triangle when its
//! centre lies inside or on the triangle (edge functions `>= 0` after orienting the triangle); its
//! depth is the barycentric interpolation of the vertex depths (linear in image space). The
//! nearest (smallest depth) triangle wins; exact depth ties go to the smaller triangle id, so the
//! result does not depend on the order the threads visit the triangles.
//!
//! Output per pixel: the winning triangle id (-1 when none), its barycentric coordinates and the
//! interpolated depth (+inf when none).

use rayon::prelude::*;

/// Rows per parallel band: small enough for load balance, large enough that the per-band bbox
/// scan over all triangles stays cheap.
const BAND_ROWS: usize = 8;

/// The result of [`rasterize`], row-major `(height, width)` buffers.
#[derive(Debug, Clone)]
pub struct Raster {
    pub width: usize,
    pub height: usize,
    /// Winning triangle per pixel, -1 for none.
    pub tri: Vec<i32>,
    /// Barycentric coordinates per pixel (`3 * width * height`), 0 for none.
    pub bary: Vec<f64>,
    /// Interpolated depth per pixel, +inf for none.
    pub depth: Vec<f64>,
}

/// Edge functions of pixel centre `(px, py)` against triangle `(a, b, c)`; `w[k]` is twice the
/// signed area of the sub-triangle opposite vertex `k`. Written out so the numpy reference can
/// repeat the exact same floating-point operations.
#[inline]
pub fn edge_functions(a: [f64; 2], b: [f64; 2], c: [f64; 2], px: f64, py: f64) -> [f64; 3] {
    let w0 = (c[0] - b[0]) * (py - b[1]) - (c[1] - b[1]) * (px - b[0]);
    let w1 = (a[0] - c[0]) * (py - c[1]) - (a[1] - c[1]) * (px - c[0]);
    let w2 = (b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0]);
    [w0, w1, w2]
}

/// Rasterize `tris` (vertex index triples) with per-vertex image coordinates `uv` and depth.
///
/// Triangles with a non-finite coordinate, an out-of-range index or zero image-space area are
/// skipped (the caller validates input; this only keeps the kernel total).
pub fn rasterize(uv: &[[f64; 2]], depth: &[f64], tris: &[[usize; 3]], width: usize, height: usize) -> Raster {
    let n = uv.len();
    // Per triangle: integer pixel bbox (inclusive) or None when unusable.
    let boxes: Vec<Option<(usize, usize, usize, usize)>> = tris
        .iter()
        .map(|t| {
            if t.iter().any(|&i| i >= n) {
                return None;
            }
            let p = [uv[t[0]], uv[t[1]], uv[t[2]]];
            if p.iter().any(|q| !q[0].is_finite() || !q[1].is_finite()) || t.iter().any(|&i| !depth[i].is_finite()) {
                return None;
            }
            let umin = p[0][0].min(p[1][0]).min(p[2][0]).ceil();
            let umax = p[0][0].max(p[1][0]).max(p[2][0]).floor();
            let vmin = p[0][1].min(p[1][1]).min(p[2][1]).ceil();
            let vmax = p[0][1].max(p[1][1]).max(p[2][1]).floor();
            if umax < 0.0 || vmax < 0.0 || umin > (width as f64 - 1.0) || vmin > (height as f64 - 1.0) || umin > umax || vmin > vmax {
                return None;
            }
            let c0 = umin.max(0.0) as usize;
            let c1 = (umax.min(width as f64 - 1.0)) as usize;
            let r0 = vmin.max(0.0) as usize;
            let r1 = (vmax.min(height as f64 - 1.0)) as usize;
            Some((r0, r1, c0, c1))
        })
        .collect();

    let mut tri = vec![-1i32; width * height];
    let mut bary = vec![0.0f64; 3 * width * height];
    let mut zbuf = vec![f64::INFINITY; width * height];
    if width == 0 || height == 0 {
        return Raster { width, height, tri, bary, depth: zbuf };
    }

    tri.par_chunks_mut(BAND_ROWS * width)
        .zip(bary.par_chunks_mut(3 * BAND_ROWS * width))
        .zip(zbuf.par_chunks_mut(BAND_ROWS * width))
        .enumerate()
        .for_each(|(band, ((tri_b, bary_b), z_b))| {
            let row0 = band * BAND_ROWS;
            let row1 = (row0 + BAND_ROWS).min(height) - 1;
            for (ti, bx) in boxes.iter().enumerate() {
                let Some((r0, r1, c0, c1)) = *bx else { continue };
                if r1 < row0 || r0 > row1 {
                    continue;
                }
                let t = tris[ti];
                let (a, b, c) = (uv[t[0]], uv[t[1]], uv[t[2]]);
                let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
                if area == 0.0 || !area.is_finite() {
                    continue;
                }
                let (da, db, dc) = (depth[t[0]], depth[t[1]], depth[t[2]]);
                for r in r0.max(row0)..=r1.min(row1) {
                    let py = r as f64;
                    for col in c0..=c1 {
                        let px = col as f64;
                        let w = edge_functions(a, b, c, px, py);
                        let (l0, l1, l2) = (w[0] / area, w[1] / area, w[2] / area);
                        if l0 < 0.0 || l1 < 0.0 || l2 < 0.0 {
                            continue;
                        }
                        let z = l0 * da + l1 * db + l2 * dc;
                        let k = (r - row0) * width + col;
                        let cur = z_b[k];
                        if z < cur || (z == cur && (ti as i32) < tri_b[k]) {
                            z_b[k] = z;
                            tri_b[k] = ti as i32;
                            bary_b[3 * k] = l0;
                            bary_b[3 * k + 1] = l1;
                            bary_b[3 * k + 2] = l2;
                        }
                    }
                }
            }
        });
    Raster { width, height, tri, bary, depth: zbuf }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_triangle_covers_expected_pixels_and_interpolates_depth() {
        let uv = [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]];
        let depth = [1.0, 2.0, 3.0];
        let r = rasterize(&uv, &depth, &[[0, 1, 2]], 6, 6);
        // Pixels with col + row <= 4 are covered (edges inclusive).
        for row in 0..6 {
            for col in 0..6 {
                let k = row * 6 + col;
                if col + row <= 4 {
                    assert_eq!(r.tri[k], 0, "({row},{col})");
                    let expect = 1.0 + (col as f64) / 4.0 + 2.0 * (row as f64) / 4.0;
                    assert!((r.depth[k] - expect).abs() < 1e-12);
                    let s: f64 = r.bary[3 * k..3 * k + 3].iter().sum();
                    assert!((s - 1.0).abs() < 1e-12);
                } else {
                    assert_eq!(r.tri[k], -1);
                    assert!(r.depth[k].is_infinite());
                }
            }
        }
    }

    #[test]
    fn nearest_wins_and_orientation_does_not_matter() {
        // Two overlapping triangles, opposite orientations; the second is nearer.
        let uv = [[0.0, 0.0], [9.0, 0.0], [0.0, 9.0], [0.0, 0.0], [0.0, 9.0], [9.0, 0.0]];
        let depth = [5.0, 5.0, 5.0, 1.0, 1.0, 1.0];
        let r = rasterize(&uv, &depth, &[[0, 1, 2], [3, 4, 5]], 10, 10);
        assert_eq!(r.tri[2 * 10 + 2], 1);
        assert_eq!(r.depth[2 * 10 + 2], 1.0);
    }

    #[test]
    fn degenerate_and_offscreen_triangles_are_skipped() {
        let uv = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [-10.0, -10.0], [-5.0, -10.0], [-10.0, -5.0]];
        let depth = [1.0; 6];
        let r = rasterize(&uv, &depth, &[[0, 1, 2], [3, 4, 5], [0, 1, 99]], 5, 5);
        assert!(r.tri.iter().all(|&t| t == -1));
    }
}
