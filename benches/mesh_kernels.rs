//! Criterion benches of the mesh kernels (issue 2): normals, areas, components, principal
//! curvatures and umbilics on a ~50k-vertex, 1 mm face-like height field with 0.05 mm noise.
//! Run: `cargo bench --bench mesh_kernels` (bench profile = release + thin LTO), 2 threads
//! (facecorr's pool; `FACECORR_THREADS` overrides).

use _core::curvature::{principal_curvatures, umbilics, CurvatureOptions, UmbilicOptions};
use _core::fixtures::grid;
use _core::mesh::{components, vertex_areas, vertex_normals, Face};
use _core::vec3::Vec3;
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

/// n x n grid, 1 mm spacing, a smooth "face" (a dome with a nose-like bump) plus
/// deterministic pseudo-random noise of ±0.05 mm.
fn face_like_grid(n: usize) -> (Vec<Vec3>, Vec<Face>) {
    let mut state: u64 = 0x9E3779B97F4A7C15;
    let c = n as f64 / 2.0;
    grid(n, n, |i, j| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let noise = ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.1;
        let (x, y) = (i as f64 - c, j as f64 - c);
        let dome = -(x * x + y * y) / 400.0;
        let nose = 25.0 * (-(x * x + (y + 10.0) * (y + 10.0)) / 200.0).exp();
        [x, y, dome + nose + noise]
    })
}

fn bench(c: &mut Criterion) {
    let (v, f) = face_like_grid(224); // 50,176 vertices, 99,458 triangles
    let pool = _core::threads::pool();
    let mut g = c.benchmark_group("mesh_kernels_50k");
    g.sample_size(20);
    g.bench_function("vertex_normals", |b| b.iter(|| pool.install(|| vertex_normals(black_box(&v), &f))));
    g.bench_function("vertex_areas", |b| b.iter(|| pool.install(|| vertex_areas(black_box(&v), &f))));
    g.bench_function("components", |b| b.iter(|| pool.install(|| components(black_box(&v), &f))));
    let opts = CurvatureOptions::default();
    g.bench_function("principal_curvatures_rings2", |b| {
        b.iter(|| pool.install(|| principal_curvatures(black_box(&v), &f, &opts)))
    });
    let opts3 = CurvatureOptions { rings: 2, radius: 3.0 };
    g.bench_function("principal_curvatures_radius3mm", |b| {
        b.iter(|| pool.install(|| principal_curvatures(black_box(&v), &f, &opts3)))
    });
    let k = pool.install(|| principal_curvatures(&v, &f, &opts));
    let uo = UmbilicOptions::default();
    g.bench_function("umbilics", |b| b.iter(|| pool.install(|| umbilics(black_box(&v), &f, &k.k1, &k.k2, &uo))));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
