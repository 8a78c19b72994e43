//! 3-D KD-tree over a fixed point set: kiddo's `ImmutableKdTree` for k-nearest queries (k > 1),
//! facecorr's own [`NearestTree`] for the single nearest point and radius queries, each built on
//! its first use (a tree queried one way pays one build). Queries are answered in parallel over
//! the query points (rayon, facecorr's pool when called through the bindings).
//!
//! Semantics follow scipy's `cKDTree`: `knn` returns, per query, the `k` nearest points sorted by
//! distance with distances strictly below `upper_bound`; missing neighbours have distance `inf`
//! and index `n` (the number of points). `within` returns every point with distance `<= r`,
//! sorted by index.

use kiddo::{ImmutableKdTree, SquaredEuclidean};

use crate::nearest::NearestTree;
use rayon::prelude::*;
use std::num::NonZeroUsize;
use std::sync::OnceLock;

/// Scratch space of one ball query: its indices, and the bitmap that orders them.
#[derive(Default)]
struct BallBuffers {
    ids: Vec<u32>,
    bits: Vec<u64>,
}

/// An immutable KD-tree over `n` points in 3-D (f64 coordinates, millimetres by convention).
pub struct KdTree3 {
    /// kiddo's tree (k-nearest queries), and facecorr's own (single-nearest and ball queries);
    /// each built on its first use, so a tree queried one way pays one build.
    tree: OnceLock<ImmutableKdTree<f64, 3>>,
    /// The single-nearest queries (the ICPs' and closest-point passes' one query): 1.2-1.5x
    /// kiddo's on scan-like data (`crate::nearest`).
    near: OnceLock<NearestTree>,
    points: Vec<[f64; 3]>,
}

impl KdTree3 {
    /// Build the tree. `points` must be finite (checked by the caller) and hold < 2^32 points.
    pub fn new(points: Vec<[f64; 3]>) -> Result<Self, String> {
        if points.len() >= u32::MAX as usize {
            return Err(format!("too many points for the KD-tree: {}", points.len()));
        }
        Ok(Self { tree: OnceLock::new(), near: OnceLock::new(), points })
    }

    fn kd(&self) -> &ImmutableKdTree<f64, 3> {
        self.tree.get_or_init(|| ImmutableKdTree::new_from_slice(&self.points).expect("kiddo tree of finite points"))
    }

    fn nt(&self) -> &NearestTree {
        self.near.get_or_init(|| NearestTree::new(&self.points))
    }

    /// The kiddo tree underneath (the benches compare the single-nearest search with it).
    pub fn kiddo(&self) -> &ImmutableKdTree<f64, 3> {
        self.kd()
    }

    /// Number of points in the tree.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the tree holds no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The points the tree was built from.
    pub fn points(&self) -> &[[f64; 3]] {
        &self.points
    }

    /// The nearest point of one query: (index, distance). The tree must not be empty.
    #[inline]
    pub fn nearest(&self, q: &[f64; 3]) -> (usize, f64) {
        let (i, d2) = self.nt().nearest(q);
        (i, d2.sqrt())
    }

    /// The `k` nearest neighbours of one query with distance `< upper_bound` (strict, as scipy),
    /// written into `dist[..k]` / `idx[..k]` (padding: `inf` / `n`).
    pub(crate) fn knn_one(&self, q: &[f64; 3], k: usize, upper_bound: f64, dist: &mut [f64], idx: &mut [u64]) {
        let n = self.points.len();
        dist.fill(f64::INFINITY);
        idx.fill(n as u64);
        if n == 0 || k == 0 {
            return;
        }
        let kk = NonZeroUsize::new(k.min(n)).unwrap();
        if k == 1 {
            let (i, d) = self.nearest(q);
            if d < upper_bound {
                dist[0] = d;
                idx[0] = i as u64;
            }
            return;
        }
        let res = if upper_bound.is_finite() {
            self.kd()
                .query(q)
                .nearest_n::<SquaredEuclidean<f64>>(kk)
                .within(upper_bound * upper_bound)
                .exclusive_boundaries()
                .execute()
        } else {
            self.kd().query(q).nearest_n::<SquaredEuclidean<f64>>(kk).execute()
        };
        let mut j = 0;
        for r in res.into_iter() {
            let d = r.distance.sqrt();
            // The squared bound can differ from the root bound in the last ulp: apply scipy's.
            if d < upper_bound && j < k {
                dist[j] = d;
                idx[j] = r.item as u64;
                j += 1;
            }
        }
    }

    /// k-nearest neighbours of every query point, in parallel. Returns row-major `(Q, k)` arrays.
    pub fn knn(&self, queries: &[[f64; 3]], k: usize, upper_bound: f64) -> (Vec<f64>, Vec<u64>) {
        // the tree the queries use, built before the parallel loop rather than inside it
        if k == 1 {
            self.nt();
        } else if k > 1 {
            self.kd();
        }
        let mut dist = vec![0.0; queries.len() * k];
        let mut idx = vec![0u64; queries.len() * k];
        if k == 0 {
            return (dist, idx);
        }
        dist.par_chunks_mut(k)
            .zip(idx.par_chunks_mut(k))
            .zip(queries.par_iter())
            .with_min_len(64)
            .for_each(|((d, i), q)| self.knn_one(q, k, upper_bound, d, i));
        (dist, idx)
    }

    /// The nearest point of every query, each searched within the distance to its `hint` (a point
    /// index, e.g. the query's nearest point before it moved a little; `>= n`: no hint): the same
    /// answer as [`knn`](Self::knn) with k = 1 (the true nearest point is never farther than the
    /// hint), found with far less backtracking when the query lies off the surface. Returns
    /// (dist (Q,), idx (Q,)).
    pub fn nearest_hinted(&self, queries: &[[f64; 3]], hints: &[u64]) -> (Vec<f64>, Vec<u64>) {
        self.nt();
        assert_eq!(queries.len(), hints.len(), "one hint per query");
        let n = self.points.len();
        let mut dist = vec![f64::INFINITY; queries.len()];
        let mut idx = vec![n as u64; queries.len()];
        if n == 0 {
            return (dist, idx);
        }
        dist.par_iter_mut()
            .zip(idx.par_iter_mut())
            .zip(queries.par_iter().zip(hints.par_iter()))
            .with_min_len(64)
            .for_each(|((d, i), (q, &h))| {
                let (j, e2) = if (h as usize) < n {
                    let p = &self.points[h as usize];
                    let (dx, dy, dz) = (q[0] - p[0], q[1] - p[1], q[2] - p[2]);
                    self.nt().nearest_within(q, h as usize, dx * dx + dy * dy + dz * dz)
                } else {
                    self.nt().nearest(q)
                };
                let e = e2.sqrt();
                *d = e;
                *i = j as u64;
            });
        (dist, idx)
    }

    /// Indices of all points with distance `<= r` of one query, sorted ascending.
    pub fn within_one(&self, q: &[f64; 3], r: f64) -> Vec<u64> {
        let mut buf = BallBuffers::default();
        self.within_sorted(q, r, &mut buf);
        buf.ids.iter().map(|&i| i as u64).collect()
    }

    /// [`within_one`](Self::within_one) into reused buffers (`buf.ids`, u32 indices). Large balls
    /// are put in order through a bitmap over their index span rather than a comparison sort
    /// (a 25 mm ball of a scan holds ~10^3 points; the sort took most of the query's time).
    fn within_sorted(&self, q: &[f64; 3], r: f64, buf: &mut BallBuffers) {
        buf.ids.clear();
        if r < 0.0 {
            return;
        }
        self.nt().within_into(q, r, &mut buf.ids);
        let ids = &mut buf.ids;
        if ids.len() < 64 {
            ids.sort_unstable();
            return;
        }
        let (lo, hi) = ids.iter().fold((u32::MAX, 0), |(a, b), &i| (a.min(i), b.max(i)));
        let words = (hi - lo) as usize / 64 + 1;
        if words > 4 * ids.len() {
            ids.sort_unstable(); // a sparse span: the sort is cheaper
            return;
        }
        let bits = &mut buf.bits;
        bits.clear();
        bits.resize(words, 0);
        for &i in ids.iter() {
            let o = (i - lo) as usize;
            bits[o / 64] |= 1u64 << (o % 64);
        }
        ids.clear();
        for (w, &word) in bits.iter().enumerate() {
            let mut x = word;
            while x != 0 {
                ids.push(lo + (w * 64) as u32 + x.trailing_zeros());
                x &= x - 1;
            }
        }
    }

    /// Indices of all points with distance `<= r` of each query (sorted ascending), in parallel.
    pub fn within(&self, queries: &[[f64; 3]], r: f64) -> Vec<Vec<u64>> {
        self.nt();
        queries.par_iter().with_min_len(16).map(|q| self.within_one(q, r)).collect()
    }

    /// Ball sums: for each query, the number of points within distance `<= r` (as `within`) and
    /// the sums of their rows of `values` (row-major, `n` rows of `c` columns). Returns (counts
    /// (Q,), sums (Q * c)). Without listing the balls (the (point, neighbour) pairs of a
    /// 56k-vertex scan at 25 mm are ~10^6-10^7): a tree box wholly inside a ball adds its
    /// precomputed sum ([`NearestTree::ball_sum`]), so a sum equals the one in point order up to
    /// rounding.
    pub fn ball_sums(&self, queries: &[[f64; 3]], r: f64, values: &[f64], c: usize) -> (Vec<u64>, Vec<f64>) {
        assert_eq!(values.len(), self.points.len() * c, "values must have one row per point");
        let nt = self.nt();
        let node_sums = nt.node_sums(values, c);
        let mut counts = vec![0u64; queries.len()];
        let mut sums = vec![0.0f64; queries.len() * c];
        if c == 0 {
            counts.par_iter_mut().zip(queries.par_iter()).with_min_len(16).for_each(|(n, q)| *n = nt.ball_sum(q, r, &node_sums, &mut []));
            return (counts, sums);
        }
        counts
            .par_iter_mut()
            .zip(sums.par_chunks_mut(c))
            .zip(queries.par_iter())
            .with_min_len(16)
            .for_each(|((n, s), q)| *n = nt.ball_sum(q, r, &node_sums, s));
        (counts, sums)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg_points(n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut next = crate::fixtures::lcg(seed);
        (0..n).map(|_| [next(), next(), next()]).collect()
    }

    fn brute_knn(p: &[[f64; 3]], q: &[f64; 3], k: usize) -> Vec<(f64, usize)> {
        let mut d: Vec<(f64, usize)> = p
            .iter()
            .enumerate()
            .map(|(i, x)| {
                let s: f64 = (0..3).map(|a| (x[a] - q[a]).powi(2)).sum();
                (s.sqrt(), i)
            })
            .collect();
        d.sort_by(|a, b| a.partial_cmp(b).unwrap());
        d.truncate(k);
        d
    }

    #[test]
    fn knn_matches_brute_force() {
        let p = lcg_points(2000, 1);
        let q = lcg_points(100, 2);
        let t = KdTree3::new(p.clone()).unwrap();
        for &k in &[1usize, 8] {
            let (d, i) = t.knn(&q, k, f64::INFINITY);
            for (qi, qq) in q.iter().enumerate() {
                let b = brute_knn(&p, qq, k);
                for j in 0..k {
                    assert!((d[qi * k + j] - b[j].0).abs() < 1e-12);
                    assert_eq!(i[qi * k + j] as usize, b[j].1);
                }
            }
        }
    }

    #[test]
    fn upper_bound_and_padding() {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [3.0, 0.0, 0.0]];
        let t = KdTree3::new(p).unwrap();
        let (d, i) = t.knn(&[[0.0, 0.0, 0.0]], 4, 2.0);
        assert_eq!(&d[..2], &[0.0, 1.0]);
        assert!(d[2].is_infinite() && d[3].is_infinite());
        assert_eq!(i, vec![0, 1, 3, 3]);
        // strict bound, as scipy
        let (d, i) = t.knn(&[[0.0, 0.0, 0.0]], 1, 0.0);
        assert!(d[0].is_infinite());
        assert_eq!(i[0], 3);
    }

    #[test]
    fn radius_query_inclusive_sorted() {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.5, 0.0, 0.0]];
        let t = KdTree3::new(p).unwrap();
        let r = t.within(&[[0.0, 0.0, 0.0]], 1.0);
        assert_eq!(r[0], vec![0, 1, 3]);
    }

    #[test]
    fn ball_sums_match_the_balls() {
        let p = lcg_points(3000, 3);
        let q = lcg_points(200, 4);
        let t = KdTree3::new(p.clone()).unwrap();
        let c = 4;
        let vals: Vec<f64> = p.iter().flat_map(|x| [x[0], x[1] * x[2], 1.0, x[0] - x[2]]).collect();
        // small balls (leaves tested point by point) to large ones (whole boxes taken)
        for r in [0.0, 0.05, 0.2, 0.6, 5.0] {
            let balls = t.within(&q, r);
            let (n, s) = t.ball_sums(&q, r, &vals, c);
            for (i, b) in balls.iter().enumerate() {
                assert_eq!(n[i] as usize, b.len());
                for k in 0..c {
                    let (mut want, mut mag) = (0.0f64, 0.0f64);
                    for &j in b {
                        want += vals[j as usize * c + k];
                        mag += vals[j as usize * c + k].abs();
                    }
                    // the same sum in another order: rounding only
                    assert!((s[i * c + k] - want).abs() <= 1e-13 * mag, "r {r} query {i} column {k}");
                }
            }
            let (n0, s0) = t.ball_sums(&q, r, &[], 0);
            assert_eq!(n0, n);
            assert!(s0.is_empty());
        }
    }

    #[test]
    fn hinted_nearest_is_the_nearest() {
        let p = lcg_points(5000, 5);
        let t = KdTree3::new(p.clone()).unwrap();
        // queries near and far off the cloud, hints good, bad and missing
        let q: Vec<[f64; 3]> = lcg_points(400, 6).into_iter().enumerate()
            .map(|(k, x)| if k % 2 == 0 { x } else { [x[0] * 9.0 - 4.0, x[1] * 9.0 - 4.0, x[2] * 9.0 - 4.0] })
            .collect();
        let (d0, i0) = t.knn(&q, 1, f64::INFINITY);
        for hint in [0u64, 17, 4999, 5000, u64::MAX] {
            let (d, i) = t.nearest_hinted(&q, &vec![hint; q.len()]);
            assert_eq!(i, i0);
            assert_eq!(d, d0);
        }
        let (d, i) = t.nearest_hinted(&q, &i0);
        assert_eq!((d, i), (d0, i0.clone()));
    }

    #[test]
    fn empty_tree() {
        let t = KdTree3::new(vec![]).unwrap();
        let (d, i) = t.knn(&[[0.0, 0.0, 0.0]], 2, f64::INFINITY);
        assert!(d.iter().all(|x| x.is_infinite()));
        assert_eq!(i, vec![0, 0]);
        assert!(t.within(&[[0.0; 3]], 1.0)[0].is_empty());
    }
}
