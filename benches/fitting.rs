//! Criterion benchmarks of the registration kernels at the template's size (5,329 vertices):
//! the shape fit's energy + gradient, one preconditioned L-BFGS solve (20 iterations), and the
//! expression fit's per-round normal equations (K = 54 shape columns + 6 rigid unknowns).
//! Run: `cargo bench --bench fitting`.

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

use _core::blend::normal_equations;
use _core::fixtures::grid;
use _core::lbfgs::{minimize_preconditioned, LbfgsOptions};
use _core::shape_fit::{energy_gradient, Adjacency, BlockPreconditioner, Correspondences, Weights, IDENTITY};

fn lcg(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64) / ((1u64 << 53) as f64) - 0.5
    }
}

/// A 73 x 73 grid (2 mm spacing) with a gentle bump, its faces and a target 1 mm above it.
fn problem() -> (Vec<[f64; 3]>, Adjacency, Correspondences) {
    let (v, f) = grid(73, 73, |i, j| {
        let (x, y) = (2.0 * i as f64 - 72.0, 2.0 * j as f64 - 72.0);
        [x, y, 20.0 * (-(x * x + y * y) / 2000.0).exp()]
    });
    let adj = Adjacency::from_faces(v.len(), &f);
    let mut r = lcg(11);
    let corr = Correspondences {
        target: v.iter().map(|p| [p[0] + 0.3 * r(), p[1] + 0.3 * r(), p[2] + 1.0]).collect(),
        normal: vec![[0.0, 0.0, 1.0]; v.len()],
        weight: (0..v.len()).map(|i| if i % 9 == 0 { 0.0 } else { 1.0 }).collect(),
        anchor: vec![None; v.len()],
        tangent: Vec::new(),
    };
    (v, adj, corr)
}

fn bench_shape(c: &mut Criterion) {
    let (v, adj, corr) = problem();
    let n = v.len();
    let w = Weights { data: 1.0, smooth: 1250.0, rigid: 0.625, landmark: 0.0, tangential: 0.0 };
    let x: Vec<f64> = (0..n).flat_map(|_| IDENTITY).collect();
    let mut grad = vec![0.0; 12 * n];
    let mut g = c.benchmark_group("shape_fit");
    g.sample_size(30);
    g.bench_function("energy+gradient 5329 vertices", |b| {
        b.iter(|| black_box(_core::threads::install(|| energy_gradient(&x, &v, &adj, &corr, w, &mut grad))))
    });
    let pc = BlockPreconditioner::new(&v, &adj, &corr, w);
    let opts = LbfgsOptions { memory: 5, max_iter: 20, rel_tol: 0.0, grad_tol: 0.0, ..Default::default() };
    g.bench_function("L-BFGS 20 iterations 5329 vertices", |b| {
        b.iter(|| {
            let mut xx = x.clone();
            _core::threads::install(|| {
                black_box(minimize_preconditioned(
                    |a: &[f64], gg: &mut [f64]| energy_gradient(a, &v, &adj, &corr, w, gg).total,
                    &mut xx,
                    &opts,
                    Some(&pc),
                ))
            })
        })
    });
    g.finish();
}

fn bench_blend(c: &mut Criterion) {
    let (n, k) = (5325usize, 54usize);
    let mut r = lcg(5);
    let basis: Vec<f64> = (0..3 * n * k).map(|_| r()).collect();
    let p3 = |r: &mut dyn FnMut() -> f64| -> Vec<[f64; 3]> { (0..n).map(|_| [r(), r(), r()]).collect() };
    let (da, qn, v) = (p3(&mut r), p3(&mut r), p3(&mut r));
    let w: Vec<f64> = (0..n).map(|i| if i % 4 == 0 { 0.0 } else { 1.0 }).collect();
    let lin = [[1.1, 0.0, 0.0], [0.0, 1.1, 0.0], [0.0, 0.0, 1.1]];
    let mut g = c.benchmark_group("expression");
    g.sample_size(30);
    g.bench_function("normal equations 5325 vertices x 60 unknowns", |b| {
        b.iter(|| black_box(_core::threads::install(|| normal_equations(&basis, k, &lin, &w, &da, &qn, &v, 0.3, true))))
    });
    g.finish();
}

criterion_group!(benches, bench_shape, bench_blend);
criterion_main!(benches);
