//! Criterion benchmarks of the Rust kernels on synthetic inputs (no files needed):
//! KD-tree build + 10k queries into 50k points (k = 1, 8); the single-nearest query near a
//! surface (facecorr's tree vs kiddo's); FMM and Dijkstra from one source on a
//! 50k-vertex wavy surface; Finger Print of 100 centres x 8 radii (up to 25 mm) on it.
//! Run: `cargo bench --bench kernels` (the Python side-by-side table: benches/compare_kernels.py).

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

use _core::fingerprint::fingerprint;
use _core::fixtures::{faces_u32, grid, lcg};
use _core::geodesic::{GeodesicSolver, Method};
use _core::kdtree::KdTree3;


/// A 224 x 224 grid (50176 vertices, spacing 1 mm) bent into a smooth bump, like a face.
fn wavy_surface() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
    let (v, f) = grid(224, 224, |i, j| {
        let (x, y) = (i as f64 - 112.0, j as f64 - 112.0);
        [x, y, 40.0 * (-(x * x + y * y) / 3000.0).exp() + 3.0 * (x / 9.0).sin()]
    });
    (v, faces_u32(f))
}

fn bench_kdtree(c: &mut Criterion) {
    let mut r = lcg(7);
    let pts: Vec<[f64; 3]> = (0..50_000).map(|_| [r() * 200.0, r() * 200.0, r() * 100.0]).collect();
    let q: Vec<[f64; 3]> = (0..10_000).map(|_| [r() * 200.0, r() * 200.0, r() * 100.0]).collect();
    let mut g = c.benchmark_group("kdtree");
    g.sample_size(20);
    for k in [1usize, 8] {
        g.bench_function(format!("build+10k queries k={k}"), |b| {
            b.iter(|| {
                let t = KdTree3::new(pts.clone()).unwrap();
                black_box(_core::threads::install(|| t.knn(&q, k, f64::INFINITY)))
            })
        });
    }
    g.finish();
    // The single-nearest query of the ICPs and closest-point passes: template-like query points
    // within 3 mm of a scan-like surface, in surface order, answered by facecorr's own tree
    // (rust/src/nearest.rs) and by kiddo's nearest_one, one thread.
    let (v, _) = wavy_surface();
    let near: Vec<[f64; 3]> = v.iter().step_by(5).map(|p| [p[0] + 0.3, p[1] - 0.2, p[2] + 6.0 * (r() - 0.5)]).collect();
    let t = KdTree3::new(v.clone()).unwrap();
    let mut g = c.benchmark_group("nearest 10k near a 50k surface");
    g.sample_size(30);
    g.bench_function("facecorr tree", |b| b.iter(|| black_box(near.iter().map(|q| t.nearest(q).0).sum::<usize>())));
    g.bench_function("kiddo nearest_one", |b| {
        b.iter(|| {
            black_box(near.iter().map(|q| t.kiddo().query(q).nearest_one::<kiddo::SquaredEuclidean<f64>>().execute().item as usize).sum::<usize>())
        })
    });
    g.finish();
}

fn bench_geodesic(c: &mut Criterion) {
    let (v, f) = wavy_surface();
    let s = GeodesicSolver::new(&v, &f).unwrap();
    let mut g = c.benchmark_group("geodesic");
    g.sample_size(20);
    g.bench_function("solver build 50k", |b| b.iter(|| black_box(GeodesicSolver::new(&v, &f).unwrap())));
    g.bench_function("fmm single source 50k", |b| {
        b.iter(|| black_box(s.distances(&[25_000], f64::INFINITY, Method::Fmm)))
    });
    g.bench_function("dijkstra single source 50k", |b| {
        b.iter(|| black_box(s.distances(&[25_000], f64::INFINITY, Method::Dijkstra)))
    });
    let mut r = lcg(3);
    let centers: Vec<u32> = (0..100).map(|_| (r() * 50_000.0) as u32).collect();
    let radii: Vec<f64> = (1..=8).map(|k| 25.0 * k as f64 / 8.0).collect();
    g.bench_function("fingerprint 100 centres x 8 radii", |b| {
        b.iter(|| black_box(_core::threads::install(|| fingerprint(&s, &centers, &radii))))
    });
    g.finish();
}

criterion_group!(benches, bench_kdtree, bench_geodesic);
criterion_main!(benches);
