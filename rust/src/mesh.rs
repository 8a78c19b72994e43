//! Triangle-mesh utilities: face normals and areas, area-weighted vertex normals, barycentric
//! vertex areas, unique edges, boundary vertices, vertex adjacency and connected components.
//!
//! Vertices are `[f64; 3]` (millimetres), faces `[usize; 3]` indices into the vertices. The
//! functions assume valid indices (the bindings check them). Per-face work runs in parallel with
//! rayon; scatter-adds into vertices are sequential (they are memory-bound and cheap).

use rayon::prelude::*;

use crate::vec3::{add, cross, norm, normalized, sub, Vec3};

pub type Face = [usize; 3];

/// (M) cross products (b - a) x (c - a): direction = face normal, length = 2 x area.
pub fn face_normals_unnormalized(v: &[Vec3], f: &[Face]) -> Vec<Vec3> {
    f.par_iter()
        .map(|t| cross(sub(v[t[1]], v[t[0]]), sub(v[t[2]], v[t[0]])))
        .collect()
}

/// (M) triangle areas.
pub fn face_areas(v: &[Vec3], f: &[Face]) -> Vec<f64> {
    f.par_iter()
        .map(|t| 0.5 * norm(cross(sub(v[t[1]], v[t[0]]), sub(v[t[2]], v[t[0]]))))
        .collect()
}

/// (N) unit area-weighted vertex normals (sum of the incident faces' unnormalised normals,
/// normalised); zero for vertices without (non-degenerate) faces.
pub fn vertex_normals(v: &[Vec3], f: &[Face]) -> Vec<Vec3> {
    let fn_ = face_normals_unnormalized(v, f);
    let mut n = vec![[0.0; 3]; v.len()];
    for (t, c) in f.iter().zip(&fn_) {
        for &i in t {
            n[i] = add(n[i], *c);
        }
    }
    n.par_iter_mut().for_each(|x| *x = normalized(*x));
    n
}

/// (N) barycentric vertex areas: a third of the area of each incident triangle.
pub fn vertex_areas(v: &[Vec3], f: &[Face]) -> Vec<f64> {
    let fa = face_areas(v, f);
    let mut a = vec![0.0; v.len()];
    for (t, &x) in f.iter().zip(&fa) {
        for &i in t {
            a[i] += x / 3.0;
        }
    }
    a
}

/// All undirected edges of all faces (3M, with repetitions), sorted, with their use count:
/// returns the unique edges `(i, j)` with `i < j` in lexicographic order and how many faces use each.
pub fn edges_with_counts(f: &[Face]) -> (Vec<[usize; 2]>, Vec<u32>) {
    // Bucketed by the smaller vertex (a counting sort, O(E)), then each bucket's few partners
    // sorted: the same lexicographic output as sorting all 3M pairs, ~4x faster on a scan.
    let n = f.iter().flat_map(|t| t.iter()).max().map_or(0, |&m| m + 1);
    let mut start = vec![0usize; n + 1];
    for t in f {
        for k in 0..3 {
            start[t[k].min(t[(k + 1) % 3]) + 1] += 1;
        }
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut partner = vec![0usize; 3 * f.len()];
    for t in f {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let (lo, hi) = if a < b { (a, b) } else { (b, a) };
            partner[fill[lo]] = hi;
            fill[lo] += 1;
        }
    }
    let mut edges: Vec<[usize; 2]> = Vec::with_capacity(3 * f.len() / 2 + 1);
    let mut counts: Vec<u32> = Vec::with_capacity(3 * f.len() / 2 + 1);
    for a in 0..n {
        let bucket = &mut partner[start[a]..start[a + 1]];
        bucket.sort_unstable();
        let mut k = 0;
        while k < bucket.len() {
            let b = bucket[k];
            let mut c = 0u32;
            while k < bucket.len() && bucket[k] == b {
                c += 1;
                k += 1;
            }
            edges.push([a, b]);
            counts.push(c);
        }
    }
    (edges, counts)
}

/// The reference of [`edges_with_counts`]: all 3M pairs sorted, then run-length counted.
#[cfg(test)]
fn edges_with_counts_by_sort(f: &[Face]) -> (Vec<[usize; 2]>, Vec<u32>) {
    let mut all: Vec<(usize, usize)> = Vec::with_capacity(3 * f.len());
    for t in f {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            all.push(if a < b { (a, b) } else { (b, a) });
        }
    }
    all.sort_unstable();
    let mut edges: Vec<[usize; 2]> = Vec::new();
    let mut counts: Vec<u32> = Vec::new();
    for e in all {
        match edges.last() {
            Some(last) if last[0] == e.0 && last[1] == e.1 => *counts.last_mut().unwrap() += 1,
            _ => {
                edges.push([e.0, e.1]);
                counts.push(1);
            }
        }
    }
    (edges, counts)
}

/// Groups of equal rows, by hashing: `(first, group)` with `first` (G) the index of each group's
/// first row, in row order, and `group` (R) each row's group (an index into `first`). O(R), where
/// sorting the rows (what `np.unique(axis=0)` and a lexsort do) is O(R log R) and 5-10x slower on a
/// scan's vertices and faces. Rows are compared as bit patterns (the caller maps -0.0 to 0.0).
pub fn first_of_equal_rows(rows: &[[u64; 3]]) -> (Vec<usize>, Vec<usize>) {
    use std::collections::HashMap;
    use std::hash::{BuildHasherDefault, Hasher};

    /// A multiply-rotate hasher (FxHash's): the keys are already well mixed coordinates.
    #[derive(Default)]
    struct Fx(u64);
    impl Hasher for Fx {
        fn write(&mut self, bytes: &[u8]) {
            for c in bytes.chunks(8) {
                let mut b = [0u8; 8];
                b[..c.len()].copy_from_slice(c);
                self.write_u64(u64::from_le_bytes(b));
            }
        }
        fn write_u64(&mut self, i: u64) {
            self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
        }
        fn finish(&self) -> u64 {
            self.0
        }
    }
    let mut seen: HashMap<[u64; 3], usize, BuildHasherDefault<Fx>> =
        HashMap::with_capacity_and_hasher(rows.len(), Default::default());
    let mut first = Vec::new();
    let group = rows
        .iter()
        .enumerate()
        .map(|(i, r)| {
            *seen.entry(*r).or_insert_with(|| {
                first.push(i);
                first.len() - 1
            })
        })
        .collect();
    (first, group)
}

/// (E) unique undirected edges `(i, j)`, `i < j`, lexicographically sorted.
pub fn edges(f: &[Face]) -> Vec<[usize; 2]> {
    edges_with_counts(f).0
}

/// Sorted ids of the vertices on a boundary edge (an edge used by exactly one face).
pub fn boundary_vertices(n_vertices: usize, f: &[Face]) -> Vec<usize> {
    let (e, c) = edges_with_counts(f);
    boundary_from_edge_counts(n_vertices, &e, &c)
}

/// Boundary vertices from [`edges_with_counts`]'s output.
pub fn boundary_from_edge_counts(n_vertices: usize, e: &[[usize; 2]], c: &[u32]) -> Vec<usize> {
    let mut on = vec![false; n_vertices];
    for (e, &c) in e.iter().zip(c) {
        if c == 1 {
            on[e[0]] = true;
            on[e[1]] = true;
        }
    }
    (0..n_vertices).filter(|&i| on[i]).collect()
}

/// Vertex adjacency in compressed form: the neighbours of vertex `i` are
/// `nbr[ptr[i]..ptr[i + 1]]`, sorted ascending, without `i` itself.
#[derive(Clone, Debug)]
pub struct Adjacency {
    pub ptr: Vec<usize>,
    pub nbr: Vec<usize>,
}

impl Adjacency {
    pub fn new(n_vertices: usize, f: &[Face]) -> Self {
        Self::from_edges(n_vertices, &edges(f))
    }

    /// From unique edges (as returned by [`edges`]).
    pub fn from_edges(n_vertices: usize, e: &[[usize; 2]]) -> Self {
        let mut deg = vec![0usize; n_vertices + 1];
        for &[a, b] in e {
            deg[a + 1] += 1;
            deg[b + 1] += 1;
        }
        for i in 0..n_vertices {
            deg[i + 1] += deg[i];
        }
        let ptr = deg;
        let mut fill = ptr.clone();
        let mut nbr = vec![0usize; 2 * e.len()];
        for &[a, b] in e {
            nbr[fill[a]] = b;
            fill[a] += 1;
            nbr[fill[b]] = a;
            fill[b] += 1;
        }
        // Edges are sorted by (a, b): the lists of `a` get their `b`s in order, but the entries
        // pushed as the second element arrive in order of `a` too, so each list is the merge of
        // two sorted runs; sort to make the order simple to rely on.
        for i in 0..n_vertices {
            nbr[ptr[i]..ptr[i + 1]].sort_unstable();
        }
        Adjacency { ptr, nbr }
    }

    #[inline]
    pub fn neighbours(&self, i: usize) -> &[usize] {
        &self.nbr[self.ptr[i]..self.ptr[i + 1]]
    }

    pub fn n_vertices(&self) -> usize {
        self.ptr.len() - 1
    }

    /// The vertices within `rings` edge hops of `i` (including `i`), in breadth-first order.
    /// `mark` must be an all-false buffer of length N; it is left all-false on return.
    pub fn rings(&self, i: usize, rings: usize, mark: &mut [bool], out: &mut Vec<usize>) {
        out.clear();
        out.push(i);
        mark[i] = true;
        let mut start = 0;
        for _ in 0..rings {
            let end = out.len();
            if start == end {
                break;
            }
            for k in start..end {
                let u = out[k];
                for &w in self.neighbours(u) {
                    if !mark[w] {
                        mark[w] = true;
                        out.push(w);
                    }
                }
            }
            start = end;
        }
        for &u in out.iter() {
            mark[u] = false;
        }
    }
}

fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

/// (N) connected-component label of each vertex, 0 = the largest by area (sum of its faces'
/// areas), then decreasing area; equal areas keep the order of their lowest vertex id. A vertex in
/// no face is a component of its own (area 0).
pub fn components(v: &[Vec3], f: &[Face]) -> Vec<usize> {
    let n = v.len();
    let mut parent: Vec<usize> = (0..n).collect();
    for t in f {
        for k in 1..3 {
            let (a, b) = (find(&mut parent, t[0]), find(&mut parent, t[k]));
            if a != b {
                // Keep the smaller id as the root: labels then follow lowest vertex ids.
                if a < b {
                    parent[b] = a
                } else {
                    parent[a] = b
                }
            }
        }
    }
    // First-appearance labels (component containing the lowest vertex id first).
    let mut label = vec![usize::MAX; n];
    let mut n_comp = 0;
    let mut lab = vec![0usize; n];
    for i in 0..n {
        let r = find(&mut parent, i);
        if label[r] == usize::MAX {
            label[r] = n_comp;
            n_comp += 1;
        }
        lab[i] = label[r];
    }
    let va = vertex_areas(v, f);
    let mut area = vec![0.0; n_comp];
    for i in 0..n {
        area[lab[i]] += va[i];
    }
    let mut order: Vec<usize> = (0..n_comp).collect();
    order.sort_by(|&a, &b| area[b].partial_cmp(&area[a]).unwrap_or(std::cmp::Ordering::Equal));
    let mut rank = vec![0usize; n_comp];
    for (r, &c) in order.iter().enumerate() {
        rank[c] = r;
    }
    lab.iter().map(|&l| rank[l]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_rows_grouped_in_first_occurrence_order() {
        let rows = [[1, 2, 3], [4, 5, 6], [1, 2, 3], [0, 0, 0], [4, 5, 6], [1, 2, 4]];
        let (first, group) = first_of_equal_rows(&rows);
        assert_eq!(first, vec![0, 1, 3, 5]);
        assert_eq!(group, vec![0, 1, 0, 2, 1, 3]);
        assert_eq!(first_of_equal_rows(&[]), (vec![], vec![]));
    }

    #[test]
    fn bucketed_edges_equal_the_sorted_reference() {
        // random faces over few vertices: repeated edges, degenerate and non-manifold ones too
        let mut x: u64 = 0x9E3779B97F4A7C15;
        let mut next = |m: usize| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % m as u64) as usize
        };
        for n in [1usize, 3, 7, 40, 500] {
            for m in [0usize, 1, 5, 200, 3000] {
                let f: Vec<Face> = (0..m).map(|_| [next(n), next(n), next(n)]).collect();
                assert_eq!(edges_with_counts(&f), edges_with_counts_by_sort(&f), "n {n} m {m}");
            }
        }
        assert_eq!(edges_with_counts(&[]), (vec![], vec![]));
    }

    /// Two triangles forming the unit square in z = 0, plus a separate small triangle.
    fn sample() -> (Vec<Vec3>, Vec<Face>) {
        let v = vec![
            [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], // the square
            [5.0, 0.0, 0.0], [5.5, 0.0, 0.0], [5.0, 0.5, 0.0], // the small triangle
        ];
        let f = vec![[0, 1, 2], [0, 2, 3], [4, 5, 6]];
        (v, f)
    }

    #[test]
    fn areas_and_normals() {
        let (v, f) = sample();
        let fa = face_areas(&v, &f);
        assert!((fa[0] - 0.5).abs() < 1e-15 && (fa[2] - 0.125).abs() < 1e-15);
        let va = vertex_areas(&v, &f);
        assert!((va[0] - 1.0 / 3.0).abs() < 1e-15);
        assert!((va[1] - 0.5 / 3.0).abs() < 1e-15);
        let total: f64 = va.iter().sum();
        assert!((total - 1.125).abs() < 1e-14);
        for n in vertex_normals(&v, &f) {
            assert!((n[2] - 1.0).abs() < 1e-15);
        }
    }

    #[test]
    fn edges_boundary_components() {
        let (v, f) = sample();
        let e = edges(&f);
        assert_eq!(e, vec![[0, 1], [0, 2], [0, 3], [1, 2], [2, 3], [4, 5], [4, 6], [5, 6]]);
        assert_eq!(boundary_vertices(v.len(), &f), vec![0, 1, 2, 3, 4, 5, 6]);
        let c = components(&v, &f);
        assert_eq!(c, vec![0, 0, 0, 0, 1, 1, 1]);
        // Make the small triangle the large one: labels swap.
        let mut v2 = v.clone();
        v2[5] = [50.0, 0.0, 0.0];
        v2[6] = [5.0, 50.0, 0.0];
        assert_eq!(components(&v2, &f), vec![1, 1, 1, 1, 0, 0, 0]);
    }

    #[test]
    fn closed_surface_has_no_boundary() {
        let f = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        assert!(boundary_vertices(4, &f).is_empty());
        let adj = Adjacency::new(4, &f);
        assert_eq!(adj.neighbours(0), &[1, 2, 3]);
        let mut mark = vec![false; 4];
        let mut out = Vec::new();
        adj.rings(0, 1, &mut mark, &mut out);
        assert_eq!(out.len(), 4);
        assert!(mark.iter().all(|m| !m));
    }

    #[test]
    fn rings_on_a_strip() {
        // A strip of triangles 0-1-2-3-4-5 (a path graph plus diagonals).
        let f = vec![[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]];
        let adj = Adjacency::new(6, &f);
        let mut mark = vec![false; 6];
        let mut out = Vec::new();
        adj.rings(0, 1, &mut mark, &mut out);
        out.sort();
        assert_eq!(out, vec![0, 1, 2]);
        adj.rings(0, 2, &mut mark, &mut out);
        out.sort();
        assert_eq!(out, vec![0, 1, 2, 3, 4]);
    }
}
