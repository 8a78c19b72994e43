//! Trimmed point-to-plane rigid ICP of a small point set (a few hundred to a few thousand template
//! points) onto the vertices of a scan, from many starting poses at once: the pose search of the
//! landmark stage (`facecorr.landmarks.pose.trimmed_icp` is the numpy reference and the
//! documentation of the method; `tests/test_pose.py` checks that the two agree).
//!
//! Per iteration: move the points, match each to its nearest scan vertex (searched within the
//! distance to its last match, [`KdTree3::nearest_hinted`]: the same matches, less backtracking),
//! keep the `keep` share with the smallest distances, stop when the trimmed RMS improved by less
//! than `tol` (relative), else take the linearised point-to-plane step (a 6×6 normal-equation
//! solve) and compose it onto the pose. Why in Rust: in numpy each iteration of a 2000-point ICP
//! spends about as long in Python overhead (sort, lstsq, cross products, array creation) as in
//! the nearest-neighbour query, and the starts run one after the other; here the starts run in
//! facecorr's pool.

use rayon::prelude::*;

use crate::kdtree::KdTree3;
use crate::vec3::{cross, dot, sub, Vec3};

/// A rigid pose x -> R x + t (R row-major).
pub type Pose = ([[f64; 3]; 3], Vec3);

/// Result of [`trimmed_icp`] from one start.
#[derive(Clone, Debug)]
pub struct IcpOutcome {
    pub pose: Pose,
    /// Trimmed RMS residual at the final pose, mm.
    pub rms: f64,
    /// Distance of every point (moved by the final pose) to its nearest scan vertex, mm.
    pub dist: Vec<f64>,
    /// Pose updates taken.
    pub iterations: usize,
    /// The trimmed RMS before the last pose update (`inf` if none): with the final pose, what
    /// [`trimmed_icp`] needs to go on exactly as if it had not stopped (its `prev` argument).
    pub prev: f64,
}

fn apply(pose: &Pose, p: &Vec3) -> Vec3 {
    let (r, t) = pose;
    [dot(r[0], *p) + t[0], dot(r[1], *p) + t[1], dot(r[2], *p) + t[2]]
}

fn matmul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    c
}

/// The rotation of the rotation vector `w` (axis × angle, radians; Rodrigues), as
/// `facecorr.geometry.transforms.rotation_from_vector`.
pub fn rotation_from_vector(w: Vec3) -> [[f64; 3]; 3] {
    let theta = dot(w, w).sqrt();
    let mut r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    if theta < 1e-15 {
        return r;
    }
    let k = [[0.0, -w[2] / theta, w[1] / theta], [w[2] / theta, 0.0, -w[0] / theta], [-w[1] / theta, w[0] / theta, 0.0]];
    let kk = matmul(&k, &k);
    let (s, c) = (theta.sin(), 1.0 - theta.cos());
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] += s * k[i][j] + c * kk[i][j];
        }
    }
    r
}

/// Least-squares solution of the symmetric positive semi-definite 6×6 system `a x = b`
/// (Cholesky with a relative ridge of 1e-12 × the mean diagonal, so that a direction the data
/// leave free, e.g. a slide along a flat patch, is not moved: numpy's lstsq would give the
/// minimum-norm step, the same in the limit).
fn solve6(mut a: [[f64; 6]; 6], mut b: [f64; 6]) -> [f64; 6] {
    let ridge = 1e-12 * (0..6).map(|i| a[i][i]).sum::<f64>() / 6.0 + 1e-300;
    for (i, row) in a.iter_mut().enumerate() {
        row[i] += ridge;
    }
    // a = L Lᵀ in place (lower triangle)
    for j in 0..6 {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if d <= 0.0 {
            return [0.0; 6];
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..6 {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    for i in 0..6 {
        for k in 0..i {
            b[i] -= a[i][k] * b[k];
        }
        b[i] /= a[i][i];
    }
    for i in (0..6).rev() {
        for k in i + 1..6 {
            b[i] -= a[k][i] * b[k];
        }
        b[i] /= a[i][i];
    }
    b
}

/// The `n_keep` smallest entries of `d`: their indices in the first `n_keep` places of `order`
/// (any order) and the RMS of those distances.
fn trimmed(d: &[f64], order: &mut [usize], n_keep: usize) -> f64 {
    for (k, o) in order.iter_mut().enumerate() {
        *o = k;
    }
    if n_keep < order.len() {
        order.select_nth_unstable_by(n_keep - 1, |&a, &b| d[a].total_cmp(&d[b]));
    }
    (order[..n_keep].iter().map(|&k| d[k] * d[k]).sum::<f64>() / n_keep as f64).sqrt()
}

/// Trimmed point-to-plane ICP of `points` onto the `tree`'s points (unit `normals`, one per tree
/// point) from `start`, at most `iters` pose updates; `keep` in (0, 1] is the share of points
/// matched, `tol` the relative RMS improvement below which it stops (see the module docs).
/// `prev`: the trimmed RMS before the step that led to `start` (`inf` for a fresh start; an
/// earlier run's [`IcpOutcome::prev`] to resume it: n + m iterations as one run of n and one of
/// m from its pose, bitwise).
pub fn trimmed_icp(points: &[Vec3], tree: &KdTree3, normals: &[Vec3], start: Pose, iters: usize, keep: f64, tol: f64,
                   prev: f64) -> IcpOutcome {
    let np = points.len();
    assert!(np > 0, "no points to align");
    assert_eq!(normals.len(), tree.len(), "one normal per scan vertex");
    let n_keep = ((keep * np as f64) as usize).max(6).min(np);
    let scan = tree.points();
    let mut pose = start;
    let mut hint = vec![u64::MAX; np];
    let mut order = vec![0usize; np];
    let mut prev = prev;
    let mut iterations = 0;
    let mut last: Option<(Vec<f64>, f64)> = None;
    let mut moved: Vec<Vec3> = Vec::with_capacity(np);
    for _ in 0..iters {
        moved.clear();
        moved.extend(points.iter().map(|p| apply(&pose, p)));
        let (d, idx) = tree.nearest_hinted(&moved, &hint);
        hint = idx;
        let rms = trimmed(&d, &mut order, n_keep);
        if prev - rms < tol * rms.max(1e-9) {
            last = Some((d, rms)); // the pose did not change: these are its final distances
            break;
        }
        prev = rms;
        let mut ata = [[0.0; 6]; 6];
        let mut atb = [0.0; 6];
        for &k in &order[..n_keep] {
            let (p, j) = (moved[k], hint[k] as usize);
            let n = normals[j];
            let c = cross(p, n);
            let row = [c[0], c[1], c[2], n[0], n[1], n[2]];
            let b = dot(sub(scan[j], p), n);
            for i in 0..6 {
                atb[i] += row[i] * b;
                for l in 0..=i {
                    ata[i][l] += row[i] * row[l];
                }
            }
        }
        for i in 0..6 {
            for l in i + 1..6 {
                ata[i][l] = ata[l][i];
            }
        }
        let x = solve6(ata, atb);
        let dr = rotation_from_vector([x[0], x[1], x[2]]);
        let t = pose.1;
        let dt = [dot(dr[0], t) + x[3], dot(dr[1], t) + x[4], dot(dr[2], t) + x[5]];
        pose = (matmul(&dr, &pose.0), dt);
        iterations += 1;
    }
    let (dist, rms) = match last {
        Some(v) => v,
        None => {
            moved.clear();
            moved.extend(points.iter().map(|p| apply(&pose, p)));
            let (d, _) = tree.nearest_hinted(&moved, &hint);
            let rms = trimmed(&d, &mut order, n_keep);
            (d, rms)
        }
    };
    IcpOutcome { pose, rms, dist, iterations, prev }
}

/// [`trimmed_icp`] from every start, the starts in parallel; `prevs` one per start (empty: all
/// fresh starts).
pub fn trimmed_icp_many(points: &[Vec3], tree: &KdTree3, normals: &[Vec3], starts: &[Pose], iters: usize, keep: f64, tol: f64,
                        prevs: &[f64]) -> Vec<IcpOutcome> {
    assert!(prevs.is_empty() || prevs.len() == starts.len(), "one prev per start");
    starts
        .par_iter()
        .enumerate()
        .map(|(k, &s)| trimmed_icp(points, tree, normals, s, iters, keep, tol, prevs.get(k).copied().unwrap_or(f64::INFINITY)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_surface(n: usize, h: f64, height: impl Fn(f64, f64) -> f64) -> (Vec<Vec3>, Vec<Vec3>) {
        // vertices of a height field and their normals (analytic, by central differences)
        let mut pts = Vec::new();
        let mut nrm = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (i as f64 * h, j as f64 * h);
                pts.push([x, y, height(x, y)]);
                let e = 1e-4;
                let gx = (height(x + e, y) - height(x - e, y)) / (2.0 * e);
                let gy = (height(x, y + e) - height(x, y - e)) / (2.0 * e);
                let l = (gx * gx + gy * gy + 1.0).sqrt();
                nrm.push([-gx / l, -gy / l, 1.0 / l]);
            }
        }
        (pts, nrm)
    }

    #[test]
    fn rotation_vector_is_a_rotation() {
        let r = rotation_from_vector([0.3, -0.2, 0.5]);
        let rt = [[r[0][0], r[1][0], r[2][0]], [r[0][1], r[1][1], r[2][1]], [r[0][2], r[1][2], r[2][2]]];
        let i = matmul(&r, &rt);
        for a in 0..3 {
            for b in 0..3 {
                assert!((i[a][b] - if a == b { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn recovers_a_small_rigid_motion() {
        // a bumpy 60 x 60 mm patch; the points are a subset of the surface moved by a known pose
        let f = |x: f64, y: f64| 6.0 * (-((x - 30.0).powi(2) + (y - 28.0).powi(2)) / 80.0).exp() + 0.01 * x * y / 10.0;
        let (scan, normals) = grid_surface(121, 0.5, f);
        let tree = KdTree3::new(scan.clone()).unwrap();
        let pts: Vec<Vec3> = scan.iter().step_by(37).filter(|p| p[0] > 8.0 && p[0] < 52.0 && p[1] > 8.0 && p[1] < 52.0).copied().collect();
        // points = R⁻¹ (scan point − t): ICP from the identity must find (R, t)
        let r = rotation_from_vector([0.02, -0.03, 0.04]);
        let t = [0.8, -0.5, 0.6];
        let moved: Vec<Vec3> = pts
            .iter()
            .map(|q| {
                let d = sub(*q, t);
                [r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2], r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2], r[0][2] * d[0] + r[1][2] * d[1] + r[2][2] * d[2]]
            })
            .collect();
        let eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let out = trimmed_icp(&moved, &tree, &normals, (eye, [0.0; 3]), 60, 0.8, 1e-9, f64::INFINITY);
        assert!(out.rms < 0.05, "rms {}", out.rms);
        for (p, q) in moved.iter().zip(&pts) {
            let d = sub(apply(&out.pose, p), *q);
            assert!(dot(d, d).sqrt() < 0.3, "{:?}", d);
        }
        assert_eq!(out.dist.len(), moved.len());
        let many = trimmed_icp_many(&moved, &tree, &normals, &[(eye, [0.0; 3]), (eye, [0.0; 3])], 60, 0.8, 1e-9, &[]);
        assert_eq!(many[0].pose, out.pose);
        assert_eq!(many[1].rms, out.rms);
    }

    #[test]
    fn resumed_runs_are_one_run() {
        // n + m iterations as one run, or as n then m from the first run's pose and prev: the same
        // pose, RMS and distances bitwise, whether the run stops early by `tol` or not
        let f = |x: f64, y: f64| 6.0 * (-((x - 30.0).powi(2) + (y - 28.0).powi(2)) / 80.0).exp() + 0.02 * x * y / 10.0;
        let (scan, normals) = grid_surface(91, 0.6, f);
        let tree = KdTree3::new(scan.clone()).unwrap();
        let pts: Vec<Vec3> = scan.iter().step_by(23).map(|p| [p[0] + 1.5, p[1] - 1.0, p[2] + 0.7]).collect();
        let start = (rotation_from_vector([0.05, -0.04, 0.08]), [0.0; 3]);
        for (tol, n, m) in [(-f64::INFINITY, 3, 7), (1e-5, 3, 7), (1e-2, 1, 9), (1e-2, 2, 8), (1e-5, 0, 6)] {
            let one = trimmed_icp(&pts, &tree, &normals, start, n + m, 0.8, tol, f64::INFINITY);
            let a = trimmed_icp(&pts, &tree, &normals, start, n, 0.8, tol, f64::INFINITY);
            let b = trimmed_icp(&pts, &tree, &normals, a.pose, m, 0.8, tol, a.prev);
            assert_eq!(b.pose, one.pose, "tol {tol} n {n}");
            assert_eq!((b.rms, &b.dist, b.prev), (one.rms, &one.dist, one.prev));
            assert_eq!(a.iterations + b.iterations, one.iterations);
        }
    }
}
