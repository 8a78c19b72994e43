//! The Finger Print descriptor (Sun & Abidi 2001; paper §3.1): for a centre vertex and a radius
//! `r`, the area of the geodesic disk `{x : d(x) <= r}` divided by `pi r^2`.
//!
//! The distance `d` is the FMM distance at the vertices, linearly interpolated inside each
//! triangle; the disk's area is exact for that piecewise-linear field (the region of a triangle
//! where a linear function is `<= r` is a triangle or a triangle minus a triangle, see
//! [`clipped_fraction`]). Each centre is one FMM propagation truncated just beyond the largest
//! radius ([`GeodesicSolver::propagate_band`]): it also accepts every vertex sharing an edge
//! with a vertex inside the largest disk, so every triangle that meets a disk has final values
//! at its three corners. Centres run in parallel,
//! each on a reusable workspace (sparse resets, no O(N) allocation per centre).

use rayon::prelude::*;

use crate::geodesic::{GeodesicSolver, Method, Workspace};

/// Fraction of a triangle's area where the linear interpolant of the corner values
/// `d0 <= d1 <= d2` is `<= r`.
#[inline]
pub fn clipped_fraction(d0: f64, d1: f64, d2: f64, r: f64) -> f64 {
    if r <= d0 {
        0.0
    } else if r >= d2 {
        1.0
    } else if r <= d1 {
        // the small triangle at corner 0 (d1 > d0 here since d0 < r <= d1)
        (r - d0) * (r - d0) / ((d1 - d0) * (d2 - d0))
    } else {
        // all but the small triangle at corner 2 (d2 > d1 and d2 > d0 here)
        1.0 - (d2 - r) * (d2 - r) / ((d2 - d0) * (d2 - d1))
    }
}

/// Disk areas for one centre after `ws` holds a band propagation covering `rmax`
/// (`radii_sorted` ascending; `out[k]` receives the area for `radii_sorted[k]`).
///
/// Every face meeting the largest disk has its three corners accepted (band property), so it is
/// visited exactly once, from its lowest-index corner.
fn disk_areas(solver: &GeodesicSolver, ws: &Workspace, radii_sorted: &[f64], rmax: f64, out: &mut [f64]) {
    out.fill(0.0);
    let faces = solver.faces();
    let areas = solver.face_areas();
    for &v in &ws.accepted {
        for fi in solver.owned_faces(v as usize) {
            let f = faces[fi];
            let (a, b, c) = (f[0] as usize, f[1] as usize, f[2] as usize);
            if !(ws.is_accepted(a) && ws.is_accepted(b) && ws.is_accepted(c)) {
                continue;
            }
            let mut d = [ws.dist(a), ws.dist(b), ws.dist(c)];
            if d[0].min(d[1]).min(d[2]) >= rmax {
                continue;
            }
            if d[0] > d[1] {
                d.swap(0, 1);
            }
            if d[1] > d[2] {
                d.swap(1, 2);
            }
            if d[0] > d[1] {
                d.swap(0, 1);
            }
            let (d0, d1, d2) = (d[0], d[1], d[2]);
            let area = areas[fi];
            for (o, &r) in out.iter_mut().zip(radii_sorted) {
                if r <= d0 {
                    continue;
                }
                if r >= d2 {
                    *o += area;
                } else {
                    *o += area * clipped_fraction(d0, d1, d2, r);
                }
            }
        }
    }
}

/// Finger Print of each centre (row-major (C, R)): disk area / (pi r^2).
pub fn fingerprint(solver: &GeodesicSolver, centers: &[u32], radii: &[f64]) -> Vec<f64> {
    let nr = radii.len();
    let mut out = vec![0.0; centers.len() * nr];
    if nr == 0 {
        return out;
    }
    let rmax = radii.iter().cloned().fold(0.0, f64::max);
    let mut order: Vec<usize> = (0..nr).collect();
    order.sort_by(|&a, &b| radii[a].total_cmp(&radii[b]));
    let sorted: Vec<f64> = order.iter().map(|&k| radii[k]).collect();
    // Centres in the solver's (Morton) vertex order: consecutive centres on a thread have
    // overlapping disks, so their mesh data is still in cache. Results go back to input order.
    let mut by_pos: Vec<(u32, usize)> =
        centers.iter().enumerate().map(|(i, &c)| (solver.internal(c), i)).collect();
    by_pos.sort_unstable();
    let mut sorted_out = vec![0.0; centers.len() * nr];
    sorted_out.par_chunks_mut(nr).zip(by_pos.par_iter()).with_min_len(8).for_each(|(row, &(c, _))| {
        let mut areas = [0.0f64; 16];
        let mut big = Vec::new();
        let acc: &mut [f64] = if nr <= 16 { &mut areas[..nr] } else { big.resize(nr, 0.0); &mut big };
        solver.with_workspace(|ws| {
            solver.propagate_band(ws, &[c], rmax, Method::Fmm);
            disk_areas(solver, ws, &sorted, rmax, acc);
        });
        for (k, &o) in order.iter().enumerate() {
            row[o] = acc[k] / (std::f64::consts::PI * sorted[k] * sorted[k]);
        }
    });
    for (row, &(_, i)) in sorted_out.chunks(nr).zip(&by_pos) {
        out[i * nr..(i + 1) * nr].copy_from_slice(row);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesic::tests::grid;

    #[test]
    fn clipped_fraction_cases() {
        assert_eq!(clipped_fraction(0.0, 1.0, 2.0, -1.0), 0.0);
        assert_eq!(clipped_fraction(0.0, 1.0, 2.0, 2.0), 1.0);
        // d = x on the triangle (0,0),(1,0),(0,1)... values 0,1,0 sorted -> (0,0,1): the region
        // x <= 0.5 of the right triangle has area fraction 1 - 0.25 = 0.75
        assert!((clipped_fraction(0.0, 0.0, 1.0, 0.5) - 0.75).abs() < 1e-15);
        assert!((clipped_fraction(0.0, 1.0, 1.0, 0.5) - 0.25).abs() < 1e-15);
        // continuity at r = d1
        let a = clipped_fraction(0.0, 0.4, 1.0, 0.4);
        let b = clipped_fraction(0.0, 0.4, 1.0, 0.4 + 1e-12);
        assert!((a - b).abs() < 1e-9);
    }

    #[test]
    fn plane_fingerprint_near_one() {
        let (v, f) = grid(60, 60, 0.25);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let c = (30 * 61 + 30) as u32;
        let fp = fingerprint(&s, &[c], &[2.0, 4.0, 6.0]);
        for x in fp {
            assert!((x - 1.0).abs() < 0.05, "{x}");
        }
    }

    #[test]
    fn fingerprint_monotone_in_area_and_stable() {
        let (v, f) = grid(30, 30, 0.5);
        let s = GeodesicSolver::new(&v, &f).unwrap();
        let a = fingerprint(&s, &[0, 400, 465], &[1.0, 3.0, 5.0]);
        let b = fingerprint(&s, &[0, 400, 465], &[1.0, 3.0, 5.0]);
        assert_eq!(a, b);
        // the corner centre sees a quarter disk
        assert!((a[2] - 0.25).abs() < 0.02, "{}", a[2]);
    }
}
