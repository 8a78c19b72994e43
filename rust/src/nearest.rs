//! Exact nearest-neighbour search in 3-D, tuned for the one query the fits repeat most: the single
//! nearest scan vertex of a template point, often with a good guess (its last match) at hand.
//!
//! A bucketed KD-tree: the points are reordered so that every leaf's ≤ [`LEAF`] points lie
//! contiguously (one column per coordinate), each node splits at the median of its points'
//! widest axis and keeps the tight box of its points, and a query opens the nearer child's box first and a
//! box only when it lies no farther than the best point so far (on a scan, a sheet in 3-D, the
//! tight boxes prune far more than the split planes). Why hand-written: the ICPs and the
//! closest-point passes of a scan spend a fifth of its time in this one query; on points near a
//! surface, in surface order, it is ~1.8x kiddo's `nearest_one` (`cargo bench --bench kernels --
//! nearest`), and kiddo's bounded search (`nearest_n(1).within`) is slower still. Ties (equal
//! distances) go to the lowest point index.

/// Points per leaf.
const LEAF: usize = 16;

#[derive(Clone, Copy, Debug)]
struct Node {
    /// Leaf: the range `start..end` of the reordered points; inner node: `end == u32::MAX` and
    /// `start` is the left child (the right one is `start + 1`).
    start: u32,
    end: u32,
    /// The tight bounding box of the node's points.
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Node {
    /// Squared distance from `q` to the node's box (0 inside).
    #[inline]
    fn box_d2(&self, q: &[f64; 3]) -> f64 {
        let mut d2 = 0.0;
        for d in 0..3 {
            let e = (self.lo[d] - q[d]).max(q[d] - self.hi[d]).max(0.0);
            d2 += e * e;
        }
        d2
    }
}

/// Per-node sums of a set of values over a [`NearestTree`]'s points ([`NearestTree::node_sums`]).
pub struct NodeSums {
    c: usize,
    /// The values' rows in the tree's leaf order.
    rows: Vec<f64>,
    /// Per node, the sum of its points' rows (`c` each), and their number.
    sums: Vec<f64>,
    counts: Vec<u32>,
}

/// The tree (see the module docs). Built once per point set; queries are `&self`.
pub struct NearestTree {
    nodes: Vec<Node>,
    /// The points in leaf order, and their indices in the input.
    xs: Vec<f64>,
    ys: Vec<f64>,
    zs: Vec<f64>,
    ids: Vec<u32>,
}

impl NearestTree {
    /// Build over `points` (finite, < 2^32 of them).
    pub fn new(points: &[[f64; 3]]) -> Self {
        let mut order: Vec<u32> = (0..points.len() as u32).collect();
        let mut nodes = vec![Node { start: 0, end: points.len() as u32, lo: [0.0; 3], hi: [0.0; 3] }];
        Self::build(points, &mut order, &mut nodes, 0, 0, points.len());
        let col = |d: usize| order.iter().map(|&i| points[i as usize][d]).collect();
        Self { nodes, xs: col(0), ys: col(1), zs: col(2), ids: order }
    }

    /// The bounding box of `points[ids]`.
    fn bounds(points: &[[f64; 3]], ids: &[u32]) -> ([f64; 3], [f64; 3]) {
        let (mut mn, mut mx) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &i in ids {
            let p = points[i as usize];
            for d in 0..3 {
                mn[d] = mn[d].min(p[d]);
                mx[d] = mx[d].max(p[d]);
            }
        }
        (mn, mx)
    }

    /// Build the subtree of `node` over `order[lo..hi]`: split at the median along the points'
    /// widest axis; the node's tight box is the union of its children's (leaves: of their points).
    fn build(points: &[[f64; 3]], order: &mut [u32], nodes: &mut Vec<Node>, node: usize, lo: usize, hi: usize) {
        if hi - lo <= LEAF {
            let (mn, mx) = Self::bounds(points, &order[lo..hi]);
            nodes[node].lo = mn;
            nodes[node].hi = mx;
            return;
        }
        // the widest axis of the points (on surface data it prunes far better than the cell's),
        // estimated on at most ~64 of them: an exact box per level would be a pass per level
        let slice = &mut order[lo..hi];
        let step = (slice.len() / 64).max(1);
        let sample: Vec<u32> = slice.iter().step_by(step).copied().collect();
        let (mn, mx) = Self::bounds(points, &sample);
        let dim = (0..3).max_by(|&a, &b| (mx[a] - mn[a]).total_cmp(&(mx[b] - mn[b]))).unwrap();
        let mid = (hi - lo) / 2;
        slice.select_nth_unstable_by(mid, |&a, &b| points[a as usize][dim].total_cmp(&points[b as usize][dim]));
        let left = nodes.len();
        nodes.push(Node { start: lo as u32, end: (lo + mid) as u32, lo: [0.0; 3], hi: [0.0; 3] });
        nodes.push(Node { start: (lo + mid) as u32, end: hi as u32, lo: [0.0; 3], hi: [0.0; 3] });
        nodes[node].start = left as u32;
        nodes[node].end = u32::MAX;
        Self::build(points, order, nodes, left, lo, lo + mid);
        Self::build(points, order, nodes, left + 1, lo + mid, hi);
        let (a, b) = (nodes[left], nodes[left + 1]);
        for d in 0..3 {
            nodes[node].lo[d] = a.lo[d].min(b.lo[d]);
            nodes[node].hi[d] = a.hi[d].max(b.hi[d]);
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// True when the tree holds no point.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The nearest point of `q`: (index, squared distance); (`n`, inf) for an empty tree.
    #[inline]
    pub fn nearest(&self, q: &[f64; 3]) -> (usize, f64) {
        self.nearest_within(q, self.len(), f64::INFINITY)
    }

    /// The nearest point of `q` given a candidate `best` at squared distance `best_d2` (e.g. its
    /// last match; `best` = `n` for none): the search only opens boxes no farther than the
    /// candidate, and the answer is the same as [`nearest`](Self::nearest)'s (ties: lowest index).
    pub fn nearest_within(&self, q: &[f64; 3], best: usize, best_d2: f64) -> (usize, f64) {
        let mut best = (best as u32, best_d2);
        if !self.ids.is_empty() && self.nodes[0].box_d2(q) <= best.1 {
            self.search(0, q, &mut best);
        }
        (best.0 as usize, best.1)
    }

    /// Append to `out` the indices of all points at distance `<= r` of `q` (as `d2.sqrt() <= r`),
    /// in no particular order. A box wholly inside the ball is taken without a distance per point.
    pub fn within_into(&self, q: &[f64; 3], r: f64, out: &mut Vec<u32>) {
        if !self.ids.is_empty() && r >= 0.0 && self.nodes[0].box_d2(q).sqrt() <= r {
            self.collect(0, q, r, out);
        }
    }

    fn collect(&self, node: usize, q: &[f64; 3], r: f64, out: &mut Vec<u32>) {
        let nd = &self.nodes[node];
        // the farthest corner: every point of the box is no farther (rounding is monotone)
        let mut far2 = 0.0;
        for d in 0..3 {
            let e = (q[d] - nd.lo[d]).abs().max((nd.hi[d] - q[d]).abs());
            far2 += e * e;
        }
        if far2.sqrt() <= r {
            let (a, b) = if nd.end != u32::MAX { (nd.start as usize, nd.end as usize) } else { self.range(node) };
            out.extend_from_slice(&self.ids[a..b]);
            return;
        }
        if nd.end != u32::MAX {
            let (a, b) = (nd.start as usize, nd.end as usize);
            for k in a..b {
                let (dx, dy, dz) = (q[0] - self.xs[k], q[1] - self.ys[k], q[2] - self.zs[k]);
                if (dx * dx + dy * dy + dz * dz).sqrt() <= r {
                    out.push(self.ids[k]);
                }
            }
            return;
        }
        for c in [nd.start as usize, nd.start as usize + 1] {
            if self.nodes[c].box_d2(q).sqrt() <= r {
                self.collect(c, q, r, out);
            }
        }
    }

    /// The sums of `values` (row-major, one row of `c` per point, input order) over every node's
    /// points, for [`ball_sum`](Self::ball_sum).
    pub fn node_sums(&self, values: &[f64], c: usize) -> NodeSums {
        assert_eq!(values.len(), self.len() * c, "values must have one row per point");
        let mut rows = Vec::with_capacity(values.len()); // in leaf order: a leaf's rows contiguous
        for &i in &self.ids {
            rows.extend_from_slice(&values[i as usize * c..(i as usize + 1) * c]);
        }
        let mut sums = vec![0.0; self.nodes.len() * c];
        let mut counts = vec![0u32; self.nodes.len()];
        // children come after their parent in `nodes`: one pass from the back fills both
        for node in (0..self.nodes.len()).rev() {
            let nd = self.nodes[node];
            let (head, tail) = sums.split_at_mut((node + 1) * c);
            let acc = &mut head[node * c..];
            if nd.end != u32::MAX {
                for k in nd.start as usize..nd.end as usize {
                    for (a, v) in acc.iter_mut().zip(&rows[k * c..(k + 1) * c]) {
                        *a += *v;
                    }
                }
                counts[node] = nd.end - nd.start;
            } else {
                let l = nd.start as usize;
                let off = (l - node - 1) * c;
                for j in 0..c {
                    acc[j] = tail[off + j] + tail[off + c + j];
                }
                counts[node] = counts[l] + counts[l + 1];
            }
        }
        NodeSums { c, rows, sums, counts }
    }

    /// The number of points at distance `<= r` of `q` (as [`within_into`](Self::within_into)),
    /// and the sum of their rows of the `sums`' values added to `out` (`c` entries). A box wholly
    /// inside the ball adds its node's sum, so the order of the additions is the tree's, not the
    /// points': equal to a sum in index order up to rounding (~1e-16 relative per addition).
    pub fn ball_sum(&self, q: &[f64; 3], r: f64, sums: &NodeSums, out: &mut [f64]) -> u64 {
        if self.ids.is_empty() || r < 0.0 || self.nodes[0].box_d2(q).sqrt() > r {
            return 0;
        }
        self.sum_node(0, q, r, sums, out)
    }

    fn sum_node(&self, node: usize, q: &[f64; 3], r: f64, sums: &NodeSums, out: &mut [f64]) -> u64 {
        let nd = &self.nodes[node];
        let c = sums.c;
        let mut far2 = 0.0;
        for d in 0..3 {
            let e = (q[d] - nd.lo[d]).abs().max((nd.hi[d] - q[d]).abs());
            far2 += e * e;
        }
        if far2.sqrt() <= r {
            for (a, v) in out.iter_mut().zip(&sums.sums[node * c..(node + 1) * c]) {
                *a += *v;
            }
            return sums.counts[node] as u64;
        }
        if nd.end != u32::MAX {
            let mut n = 0;
            for k in nd.start as usize..nd.end as usize {
                let (dx, dy, dz) = (q[0] - self.xs[k], q[1] - self.ys[k], q[2] - self.zs[k]);
                if (dx * dx + dy * dy + dz * dz).sqrt() <= r {
                    for (a, v) in out.iter_mut().zip(&sums.rows[k * c..(k + 1) * c]) {
                        *a += *v;
                    }
                    n += 1;
                }
            }
            return n;
        }
        let mut n = 0;
        for ch in [nd.start as usize, nd.start as usize + 1] {
            if self.nodes[ch].box_d2(q).sqrt() <= r {
                n += self.sum_node(ch, q, r, sums, out);
            }
        }
        n
    }

    /// The range of reordered points under an inner node (its leftmost and rightmost leaves').
    fn range(&self, node: usize) -> (usize, usize) {
        let (mut l, mut r) = (node, node);
        while self.nodes[l].end == u32::MAX {
            l = self.nodes[l].start as usize;
        }
        while self.nodes[r].end == u32::MAX {
            r = self.nodes[r].start as usize + 1;
        }
        (self.nodes[l].start as usize, self.nodes[r].end as usize)
    }

    /// Descend from `node` (its box already found no farther than the best so far).
    fn search(&self, node: usize, q: &[f64; 3], best: &mut (u32, f64)) {
        let nd = &self.nodes[node];
        if nd.end != u32::MAX {
            let (a, b) = (nd.start as usize, nd.end as usize);
            // distances first (vectorised over the leaf's coordinate columns), then the minimum
            let mut d2s = [f64::INFINITY; LEAF];
            let (xs, ys, zs) = (&self.xs[a..b], &self.ys[a..b], &self.zs[a..b]);
            for k in 0..b - a {
                let (dx, dy, dz) = (q[0] - xs[k], q[1] - ys[k], q[2] - zs[k]);
                d2s[k] = dx * dx + dy * dy + dz * dz;
            }
            for (k, &d2) in d2s[..b - a].iter().enumerate() {
                if d2 < best.1 || (d2 == best.1 && self.ids[a + k] < best.0) {
                    *best = (self.ids[a + k], d2);
                }
            }
            return;
        }
        let (l, r) = (nd.start as usize, nd.start as usize + 1);
        let (dl, dr) = (self.nodes[l].box_d2(q), self.nodes[r].box_d2(q));
        let ((a, da), (b, db)) = if dl <= dr { ((l, dl), (r, dr)) } else { ((r, dr), (l, dl)) };
        if da <= best.1 {
            self.search(a, q, best);
        }
        if db <= best.1 {
            self.search(b, q, best);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pseudo_points(n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut r = crate::fixtures::lcg(seed);
        let mut next = || r() * 100.0 - 50.0;
        (0..n).map(|_| [next(), next(), next() * 0.2]).collect()
    }

    fn brute(pts: &[[f64; 3]], q: &[f64; 3]) -> (usize, f64) {
        let mut best = (pts.len(), f64::INFINITY);
        for (i, p) in pts.iter().enumerate() {
            let d2 = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2);
            if d2 < best.1 {
                best = (i, d2);
            }
        }
        best
    }

    #[test]
    fn matches_brute_force_with_and_without_a_candidate() {
        for n in [0usize, 1, 5, 12, 13, 100, 3000] {
            let pts = pseudo_points(n, n as u64 + 1);
            let tree = NearestTree::new(&pts);
            for q in pseudo_points(200, 99) {
                let want = brute(&pts, &q);
                assert_eq!(tree.nearest(&q), want);
                if n > 0 {
                    let c = (q[0].abs() as usize * 7) % n; // any point: its distance bounds the answer
                    let d2 = (q[0] - pts[c][0]).powi(2) + (q[1] - pts[c][1]).powi(2) + (q[2] - pts[c][2]).powi(2);
                    assert_eq!(tree.nearest_within(&q, c, d2), want);
                }
            }
        }
    }

    #[test]
    fn balls_match_brute_force() {
        for n in [0usize, 1, 13, 100, 3000] {
            let pts = pseudo_points(n, n as u64 + 5);
            let tree = NearestTree::new(&pts);
            for (qi, q) in pseudo_points(100, 7).iter().enumerate() {
                let r = [0.0, 1.0, 8.0, 30.0, 200.0][qi % 5];
                let mut got = Vec::new();
                tree.within_into(q, r, &mut got);
                got.sort_unstable();
                let want: Vec<u32> = (0..n as u32)
                    .filter(|&i| {
                        let p = pts[i as usize];
                        let (dx, dy, dz) = (q[0] - p[0], q[1] - p[1], q[2] - p[2]);
                        (dx * dx + dy * dy + dz * dz).sqrt() <= r
                    })
                    .collect();
                assert_eq!(got, want);
            }
        }
    }

    #[test]
    fn ties_go_to_the_lowest_index() {
        let pts = vec![[1.0, 0.0, 0.0]; 40];
        let tree = NearestTree::new(&pts);
        assert_eq!(tree.nearest(&[0.0, 0.0, 0.0]), (0, 1.0));
        assert_eq!(tree.nearest_within(&[0.0, 0.0, 0.0], 17, 1.0), (0, 1.0));
    }
}

