//! Normal equations of one round of the blendshape (+ identity) expression fit (paper §4.2).
//!
//! The fitted template is p_i(x) = base_i + L B_i a + ω × v_i + t with x = (a, ω, t): a the K
//! shape weights (blendshapes, identity modes), B_i (3 × K) vertex i's rows of the shape basis,
//! L the alignment's linear part, v_i the vertex relative to the rotation centre, and (ω, t) a
//! small rigid correction (optional). With the nearest neighbours fixed the data energy
//!
//!   E(x) = Σ_i w_i [ (1 − λ) (c_i − J_i x)² + λ ‖da_i − S_i x‖² ],
//!   S_i = [L B_i | −[v_i]× | I],  J_i = n_iᵀ S_i,  c_i = ⟨da_i, n_i⟩,  da_i = q_i − base_i,
//!
//! is the quadratic xᵀHx − 2gᵀx + c; [`normal_equations`] returns H, g and c **without** the
//! point-to-point shape block λ Σ_i w_i (L B_i)ᵀ(L B_i): for a similarity L = sR it is
//! λ s² Σ_i w_i B_iᵀB_i, which the caller keeps up to date from the vertices whose weight changed
//! (most of the work of a round otherwise). One pass over the matched vertices, in parallel,
//! with no per-vertex Jacobian stored (the Python version gathered (N, 3, K) arrays per round).

use rayon::prelude::*;

use crate::vec3::{cross, dot};

/// Output of [`normal_equations`]: H row-major (n_x × n_x, symmetric), g (n_x), c.
#[derive(Clone, Debug, PartialEq)]
pub struct NormalEquations {
    pub n_x: usize,
    pub h: Vec<f64>,
    pub g: Vec<f64>,
    pub c: f64,
}

/// Vertices whose plane rows are added to H together (a rank-GROUP update: each H entry loaded
/// and stored once per group, not once per vertex, which bounded the loop).
const GROUP: usize = 4;

struct Acc {
    h: Vec<f64>, // upper triangle used, row-major n_x × n_x
    g: Vec<f64>,
    c: f64,
    jac: Vec<f64>,
    scaled: Vec<f64>,
}

impl Acc {
    fn new(n_x: usize) -> Self {
        Self {
            h: vec![0.0; n_x * n_x],
            g: vec![0.0; n_x],
            c: 0.0,
            jac: vec![0.0; GROUP * n_x],
            scaled: vec![0.0; GROUP * n_x],
        }
    }
    fn add(mut self, o: Acc) -> Acc {
        self.h.iter_mut().zip(&o.h).for_each(|(a, b)| *a += b);
        self.g.iter_mut().zip(&o.g).for_each(|(a, b)| *a += b);
        self.c += o.c;
        self
    }
}

struct Ctx<'a> {
    basis: &'a [f64],
    k: usize,
    lin: &'a [[f64; 3]; 3],
    w: &'a [f64],
    da: &'a [[f64; 3]],
    qn: &'a [[f64; 3]],
    v: &'a [[f64; 3]],
    lam: f64,
    rigid: bool,
    n_x: usize,
}

fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The same loop compiled for AVX2 + FMA (the wheel targets baseline x86-64; the rank-one
/// updates of H are ~3x faster with 4-wide fused multiply-adds).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_avx2(acc: &mut Acc, chunk: &[usize], ctx: &Ctx) {
    accumulate(acc, chunk, ctx)
}

/// Add the matched vertices `chunk` to `acc`.
#[inline(always)]
fn accumulate(acc: &mut Acc, chunk: &[usize], ctx: &Ctx) {
    #[rustfmt::skip]
    let Ctx { basis, k, lin, w, da, qn, v, lam, rigid, n_x } = *ctx;
    let pw_scale = 1.0 - lam;
    // jac holds the plane rows J_i of up to GROUP vertices, scaled their rows pw·J_i
    let mut filled = 0usize;
    for (pos, &i) in chunk.iter().enumerate() {
        let wi = w[i];
        let (d, nn, vi) = (&da[i], &qn[i], &v[i]);
        let rows = &basis[3 * i * k..3 * (i + 1) * k];
        let (b0, b1, b2) = (&rows[..k], &rows[k..2 * k], &rows[2 * k..]);
        // m = Lᵀ n: the plane row of the shape columns is mᵀ B_i
        let m = [
            lin[0][0] * nn[0] + lin[1][0] * nn[1] + lin[2][0] * nn[2],
            lin[0][1] * nn[0] + lin[1][1] * nn[1] + lin[2][1] * nn[2],
            lin[0][2] * nn[0] + lin[1][2] * nn[1] + lin[2][2] * nn[2],
        ];
        let jac = &mut acc.jac[filled * n_x..(filled + 1) * n_x];
        for c in 0..k {
            jac[c] = m[0] * b0[c] + m[1] * b1[c] + m[2] * b2[c];
        }
        if rigid {
            // n · (ω × v) = ω · (v × n)
            jac[k..k + 3].copy_from_slice(&cross(*vi, *nn));
            jac[k + 3..k + 6].copy_from_slice(nn);
        }
        let ci = dot(*d, *nn);
        let pw = pw_scale * wi;
        for a in 0..n_x {
            let s = pw * jac[a];
            acc.scaled[filled * n_x + a] = s;
            acc.g[a] += s * ci;
        }
        filled += 1;
        if filled == GROUP || pos + 1 == chunk.len() {
            add_rank_group(&mut acc.h, &acc.jac, &acc.scaled, filled, n_x);
            filled = 0;
        }
        acc.c += pw * ci * ci;
        if lam > 0.0 {
            let lw = lam * wi;
            // g_shape += λ w B_iᵀ (Lᵀ da)
            let e = [
                lin[0][0] * d[0] + lin[1][0] * d[1] + lin[2][0] * d[2],
                lin[0][1] * d[0] + lin[1][1] * d[1] + lin[2][1] * d[2],
                lin[0][2] * d[0] + lin[1][2] * d[1] + lin[2][2] * d[2],
            ];
            for c in 0..k {
                acc.g[c] += lw * (e[0] * b0[c] + e[1] * b1[c] + e[2] * b2[c]);
            }
            acc.c += lw * dot(*d, *d);
            if rigid {
                // R = [−[v]× | I] (3 × 6), row by row; Q = Lᵀ R
                let r: [[f64; 6]; 3] = [
                    [0.0, vi[2], -vi[1], 1.0, 0.0, 0.0],
                    [-vi[2], 0.0, vi[0], 0.0, 1.0, 0.0],
                    [vi[1], -vi[0], 0.0, 0.0, 0.0, 1.0],
                ];
                let mut q = [[0.0; 6]; 3];
                for a in 0..3 {
                    for c in 0..6 {
                        q[a][c] = lin[0][a] * r[0][c] + lin[1][a] * r[1][c] + lin[2][a] * r[2][c];
                    }
                }
                // shape × rigid block: λ w B_iᵀ Q
                for c in 0..k {
                    let row = &mut acc.h[c * n_x + k..c * n_x + k + 6];
                    let (x0, x1, x2) = (lw * b0[c], lw * b1[c], lw * b2[c]);
                    for s in 0..6 {
                        row[s] += x0 * q[0][s] + x1 * q[1][s] + x2 * q[2][s];
                    }
                }
                // rigid × rigid: λ w RᵀR, and g_rigid += λ w Rᵀ da
                for s in 0..6 {
                    acc.g[k + s] += lw * (r[0][s] * d[0] + r[1][s] * d[1] + r[2][s] * d[2]);
                    for t in s..6 {
                        acc.h[(k + s) * n_x + k + t] +=
                            lw * (r[0][s] * r[0][t] + r[1][s] * r[1][t] + r[2][s] * r[2][t]);
                    }
                }
            }
        }
    }
}

/// H[a][b] += Σ_v scaled[v][a] jac[v][b] over the `filled` vertices of a group, upper triangle.
#[inline(always)]
fn add_rank_group(h: &mut [f64], jac: &[f64], scaled: &[f64], filled: usize, n_x: usize) {
    let j = |v: usize| &jac[v * n_x..(v + 1) * n_x];
    let sc = |v: usize, a: usize| scaled[v * n_x + a];
    if filled == GROUP {
        let (j0, j1, j2, j3) = (j(0), j(1), j(2), j(3));
        for a in 0..n_x {
            let (s0, s1, s2, s3) = (sc(0, a), sc(1, a), sc(2, a), sc(3, a));
            let row = &mut h[a * n_x + a..(a + 1) * n_x];
            for (((hb, (x0, x1)), x2), x3) in row.iter_mut().zip(j0[a..].iter().zip(&j1[a..])).zip(&j2[a..]).zip(&j3[a..]) {
                *hb += s0 * x0 + s1 * x1 + s2 * x2 + s3 * x3;
            }
        }
    } else {
        for v in 0..filled {
            let jv = j(v);
            for a in 0..n_x {
                let s = sc(v, a);
                let row = &mut h[a * n_x + a..(a + 1) * n_x];
                for (hb, jb) in row.iter_mut().zip(&jv[a..]) {
                    *hb += s * jb;
                }
            }
        }
    }
}

/// H, g, c of the module docs (H without the point-to-point shape block).
///
/// `basis`: (3N × k) row-major, row 3i + d = coordinate d of vertex i's k shape columns;
/// `lin`: L row-major; `w` (N) weights (≤ 0 = no match); `da`, `qn`, `v` (N) as in the module
/// docs; `lam` = λ ∈ [0, 1); `rigid`: include the 6 rigid unknowns (n_x = k + 6, else k).
#[allow(clippy::too_many_arguments)]
pub fn normal_equations(
    basis: &[f64],
    k: usize,
    lin: &[[f64; 3]; 3],
    w: &[f64],
    da: &[[f64; 3]],
    qn: &[[f64; 3]],
    v: &[[f64; 3]],
    lam: f64,
    rigid: bool,
) -> NormalEquations {
    let n = w.len();
    assert!(
        basis.len() == 3 * n * k,
        "basis has {} numbers, expected 3 x {n} x {k}",
        basis.len()
    );
    assert!(
        da.len() == n && qn.len() == n && v.len() == n,
        "per-vertex arrays differ in length"
    );
    let n_x = k + if rigid { 6 } else { 0 };
    let active: Vec<usize> = (0..n).filter(|&i| w[i] > 0.0).collect();
    #[rustfmt::skip]
    let ctx = Ctx { basis, k, lin, w, da, qn, v, lam, rigid, n_x };
    let avx2 = has_avx2_fma();
    let acc = active
        .par_chunks(256)
        .fold(
            || Acc::new(n_x),
            |mut acc, chunk| {
                if avx2 {
                    // SAFETY: the CPU has AVX2 and FMA (checked at run time).
                    #[cfg(target_arch = "x86_64")]
                    unsafe {
                        accumulate_avx2(&mut acc, chunk, &ctx)
                    };
                } else {
                    accumulate(&mut acc, chunk, &ctx);
                }
                acc
            },
        )
        .reduce(|| Acc::new(n_x), Acc::add);
    let mut h = acc.h;
    for a in 0..n_x {
        for b in 0..a {
            h[a * n_x + b] = h[b * n_x + a];
        }
    }
    NormalEquations {
        n_x,
        h,
        g: acc.g,
        c: acc.c,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vec3::norm;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64) - 0.5
    }

    #[test]
    fn quadratic_form_reproduces_the_energy() {
        let (n, k) = (40, 5);
        let mut sd = 7u64;
        let basis: Vec<f64> = (0..3 * n * k).map(|_| lcg(&mut sd)).collect();
        let lin = [[1.1, 0.2, -0.1], [0.05, 0.9, 0.3], [-0.2, 0.1, 1.2]]; // not a similarity
        let w: Vec<f64> = (0..n)
            .map(|i| if i % 5 == 0 { 0.0 } else { 0.5 + lcg(&mut sd) })
            .collect();
        let p3 = |sd: &mut u64| -> Vec<[f64; 3]> { (0..n).map(|_| [lcg(sd), lcg(sd), lcg(sd)]).collect() };
        let da = p3(&mut sd);
        let v = p3(&mut sd);
        let qn: Vec<[f64; 3]> = p3(&mut sd)
            .into_iter()
            .map(|a| {
                let l = norm(a);
                [a[0] / l, a[1] / l, a[2] / l]
            })
            .collect();
        let lam = 0.3;
        // E(x) by its definition, for checking xᵀHx − 2gᵀx + c (with the shape block added)
        let energy = |x: &[f64]| -> f64 {
            let mut e = 0.0;
            for i in 0..w.len() {
                if w[i] <= 0.0 {
                    continue;
                }
                let mut off = [0.0; 3]; // B_i a
                for d in 0..3 {
                    off[d] = (0..k).map(|c| basis[(3 * i + d) * k + c] * x[c]).sum();
                }
                let mut s = [0.0; 3];
                for r in 0..3 {
                    s[r] = lin[r][0] * off[0] + lin[r][1] * off[1] + lin[r][2] * off[2];
                }
                let (om, t) = (&x[k..k + 3], &x[k + 3..k + 6]);
                let vi = v[i];
                let cr = [
                    om[1] * vi[2] - om[2] * vi[1],
                    om[2] * vi[0] - om[0] * vi[2],
                    om[0] * vi[1] - om[1] * vi[0],
                ];
                for r in 0..3 {
                    s[r] += cr[r] + t[r];
                }
                let rp = dot(da[i], qn[i]) - dot(s, qn[i]);
                let rr: f64 = (0..3).map(|r| (da[i][r] - s[r]).powi(2)).sum();
                e += w[i] * ((1.0 - lam) * rp * rp + lam * rr);
            }
            e
        };
        let ne = normal_equations(&basis, k, &lin, &w, &da, &qn, &v, lam, true);
        let nx = ne.n_x;
        // add the shape block λ Σ w (L B_i)ᵀ(L B_i) the caller supplies
        let mut h = ne.h.clone();
        for i in 0..n {
            if w[i] <= 0.0 {
                continue;
            }
            let mut u = vec![[0.0; 3]; k]; // column c of L B_i
            for c in 0..k {
                for r in 0..3 {
                    u[c][r] = (0..3).map(|d| lin[r][d] * basis[(3 * i + d) * k + c]).sum();
                }
            }
            for a in 0..k {
                for b in 0..k {
                    h[a * nx + b] += lam * w[i] * dot(u[a], u[b]);
                }
            }
        }
        for trial in 0..5 {
            let x: Vec<f64> = (0..nx).map(|_| lcg(&mut sd) * (1.0 + trial as f64)).collect();
            let hx: Vec<f64> = (0..nx).map(|a| (0..nx).map(|b| h[a * nx + b] * x[b]).sum()).collect();
            let q: f64 = x.iter().zip(&hx).map(|(a, b)| a * b).sum::<f64>()
                - 2.0 * x.iter().zip(&ne.g).map(|(a, b)| a * b).sum::<f64>()
                + ne.c;
            let e = energy(&x);
            assert!((q - e).abs() <= 1e-10 * e.abs().max(1.0), "trial {trial}: {q} vs {e}");
        }
        for a in 0..nx {
            for b in 0..nx {
                assert_eq!(ne.h[a * nx + b], ne.h[b * nx + a]);
            }
        }
    }
}
