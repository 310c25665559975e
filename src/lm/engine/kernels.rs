//! The plain-code numerics under choreo's local kernel
//! ([`super::local_kernel`]): a row-major product with a bias in register
//! tiles (AVX2 and FMA where the CPU has them, picked at run time; SSE
//! otherwise), LayerNorm, GELU in the exported graphs' erf form, and the
//! erf the trainer's fused GELU shares.

pub(super) fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// LayerNorm of each `d`-long row of `x` into `y` (ONNX's
/// `LayerNormalization` over the last axis: biased variance).
pub(super) fn layer_norm(
    x: &[f32],
    d: usize,
    (g, b): &(Vec<f32>, Vec<f32>),
    eps: f32,
    y: &mut Vec<f32>,
) {
    y.resize(x.len(), 0.0);
    for (xr, yr) in x.chunks_exact(d).zip(y.chunks_exact_mut(d)) {
        let mean = xr.iter().sum::<f32>() / d as f32;
        let var = xr.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / d as f32;
        let inv = 1.0 / (var + eps).sqrt();
        for (((y, &x), &g), &b) in yr.iter_mut().zip(xr).zip(g).zip(b) {
            *y = (x - mean) * inv * g + b;
        }
    }
}

/// GELU in the exported graph's form: `x (1 + erf(x / √2)) / 2`.
pub(super) fn gelu(x: f32) -> f32 {
    x * (1.0 + erf(x / std::f32::consts::SQRT_2)) * 0.5
}

/// `out = x · w + b` for `rows` rows of `x` (`w`: `[k, m]` row-major,
/// `k = x.len() / rows`, `m = b.len()`).
pub(super) fn gemm(x: &[f32], rows: usize, w: &[f32], b: &[f32], out: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        unsafe { gemm_avx2(x, rows, w, b, out) };
        return;
    }
    gemm_body::<false>(x, rows, w, b, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn gemm_avx2(x: &[f32], rows: usize, w: &[f32], b: &[f32], out: &mut [f32]) {
    gemm_body::<true>(x, rows, w, b, out)
}

/// The product in tiles of four rows by [`TILE`] columns, each tile's
/// sums held in registers over the whole inner dimension (eight AVX
/// registers), so a weight is loaded once for four rows and an output
/// written once; leftover rows one at a time, leftover columns by a plain
/// loop. Each sum starts from the bias and adds the terms in order.
#[inline(always)]
fn gemm_body<const FMA: bool>(x: &[f32], rows: usize, w: &[f32], b: &[f32], out: &mut [f32]) {
    let m = b.len();
    let k = x.len() / rows.max(1);
    debug_assert_eq!(w.len(), k * m);
    let mut r0 = 0;
    while r0 + 4 <= rows {
        tile_rows::<4, FMA>(
            &x[r0 * k..(r0 + 4) * k],
            w,
            b,
            &mut out[r0 * m..(r0 + 4) * m],
        );
        r0 += 4;
    }
    while r0 < rows {
        tile_rows::<1, FMA>(
            &x[r0 * k..(r0 + 1) * k],
            w,
            b,
            &mut out[r0 * m..(r0 + 1) * m],
        );
        r0 += 1;
    }
}

/// Columns a tile spans: two AVX registers.
const TILE: usize = 16;

#[inline(always)]
fn fma<const FMA: bool>(a: f32, w: f32, acc: f32) -> f32 {
    if FMA {
        a.mul_add(w, acc)
    } else {
        acc + a * w
    }
}

/// `R` rows of `x` (`[R, k]`) times `w` (`[k, m]`) plus `b` into `out`
/// (`[R, m]`).
#[inline(always)]
fn tile_rows<const R: usize, const FMA: bool>(x: &[f32], w: &[f32], b: &[f32], out: &mut [f32]) {
    let m = b.len();
    let k = x.len() / R;
    let mut c0 = 0;
    while c0 + TILE <= m {
        let mut acc = [[0f32; TILE]; R];
        for a in acc.iter_mut() {
            a.copy_from_slice(&b[c0..c0 + TILE]);
        }
        for kk in 0..k {
            let wt: &[f32; TILE] = w[kk * m + c0..kk * m + c0 + TILE]
                .try_into()
                .expect("a tile's width");
            for (r, acc) in acc.iter_mut().enumerate() {
                let a = x[r * k + kk];
                for (s, &wv) in acc.iter_mut().zip(wt) {
                    *s = fma::<FMA>(a, wv, *s);
                }
            }
        }
        for (r, acc) in acc.iter().enumerate() {
            out[r * m + c0..r * m + c0 + TILE].copy_from_slice(acc);
        }
        c0 += TILE;
    }
    if c0 < m {
        for r in 0..R {
            let o = &mut out[r * m + c0..(r + 1) * m];
            o.copy_from_slice(&b[c0..]);
            for kk in 0..k {
                let a = x[r * k + kk];
                for (s, &wv) in o.iter_mut().zip(&w[kk * m + c0..(kk + 1) * m]) {
                    *s = fma::<FMA>(a, wv, *s);
                }
            }
        }
    }
}

/// Past this, erf(x) rounds to ±1 in f32 (1 − erf(3.92) = 4e-8).
const ERF_SATURATES: f32 = 3.92;
/// erf(x) ≈ x P(x²) / Q(x²) on |x| ≤ [`ERF_SATURATES`], clamped to ±1:
/// within 4.4e-7 of the exact erf (scipy's float64, 2·10⁶ points on [0,
/// 6]; libm's float64 in `train::fused::tests`, 10⁶ points on [−6, 6]),
/// about 7 ulp of 1.0 at worst. Branch-free, so a loop over it
/// vectorises; libm's `erff` (candle's erf) takes a branch and an `exp`
/// per value, and GELU with it was 15 % of a training step. The
/// coefficients were fitted here (iteratively reweighted least squares
/// for the rational form on [0, 3.92], then rounded to f32). An exported
/// graph keeps ONNX's `Erf`: the trainer-to-tract parity after the change
/// read 9.5e-6 on logits up to 9.9. The trainer (`train::fused`) and the
/// local kernel's GELU share it.
#[inline(always)]
pub(crate) fn erf(x: f32) -> f32 {
    // Fitted coefficients; the first is close to 2/√π by the series, not by
    // being that constant.
    #[allow(clippy::approx_constant)]
    const P: [f32; 6] = [
        1.128_379_1,
        0.190_650_17,
        0.052_801_233,
        0.003_783_061_2,
        0.000_286_497_52,
        2.063_373_4e-6,
    ];
    const Q: [f32; 6] = [
        1.0,
        0.502_291_44,
        0.114_229_1,
        0.015_001_096,
        0.001_169_166_5,
        3.831_572_8e-5,
    ];
    // Selects, not `f32::min`, so that a NaN stays NaN.
    let a = x.abs();
    let a = if a > ERF_SATURATES { ERF_SATURATES } else { a };
    let u = a * a;
    let p = P.iter().rev().fold(0.0f32, |acc, &c| acc * u + c);
    let q = Q.iter().rev().fold(0.0f32, |acc, &c| acc * u + c);
    let r = a * p / q;
    (if r > 1.0 { 1.0 } else { r }).copysign(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both code paths of the product (and the run-time pick) against a
    /// plain triple loop in f64, over row counts with and without a
    /// leftover row and widths with and without leftover columns.
    #[test]
    fn the_product_is_the_plain_one() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        for (rows, k, m) in [
            (1, 5, 3),
            (4, 64, 192),
            (5, 64, 360),
            (3, 256, 64),
            (8, 7, 17),
        ] {
            let x: Vec<f32> = (0..rows * k).map(|_| next()).collect();
            let w: Vec<f32> = (0..k * m).map(|_| next()).collect();
            let b: Vec<f32> = (0..m).map(|_| next()).collect();
            let want: Vec<f64> = (0..rows * m)
                .map(|i| {
                    let (r, c) = (i / m, i % m);
                    b[c] as f64
                        + (0..k)
                            .map(|j| x[r * k + j] as f64 * w[j * m + c] as f64)
                            .sum::<f64>()
                })
                .collect();
            let mut got = [
                vec![0f32; rows * m],
                vec![0f32; rows * m],
                vec![0f32; rows * m],
            ];
            gemm_body::<false>(&x, rows, &w, &b, &mut got[0]);
            gemm_body::<true>(&x, rows, &w, &b, &mut got[1]);
            gemm(&x, rows, &w, &b, &mut got[2]);
            for g in &got {
                for (a, e) in g.iter().zip(&want) {
                    assert!((*a as f64 - e).abs() < 1e-4, "{rows}x{k}x{m}: {a} vs {e}");
                }
            }
        }
    }

    #[test]
    fn gelu_and_layer_norm_are_the_textbook_ones() {
        for x in [-3.0f32, -0.5, 0.0, 0.7, 2.5] {
            let want = 0.5 * x as f64 * (1.0 + libm_erf(x as f64 / 2f64.sqrt()));
            assert!((gelu(x) as f64 - want).abs() < 1e-6, "{x}");
        }
        let x = [1.0f32, 2.0, 4.0, 9.0];
        let (g, b) = (vec![2.0f32; 4], vec![0.5f32; 4]);
        let mut y = Vec::new();
        layer_norm(&x, 4, &(g, b), 1e-5, &mut y);
        let mean = 4.0f64;
        let var = (9.0 + 4.0 + 0.0 + 25.0) / 4.0;
        for (yv, xv) in y.iter().zip(x) {
            let want = (xv as f64 - mean) / (var + 1e-5f64).sqrt() * 2.0 + 0.5;
            assert!((*yv as f64 - want).abs() < 1e-5);
        }
    }

    /// erf by its series (|x| ≤ 3: 60 terms are plenty in f64).
    fn libm_erf(x: f64) -> f64 {
        let mut term = x;
        let mut sum = x;
        for n in 1..60 {
            term *= -x * x / n as f64;
            sum += term / (2 * n + 1) as f64;
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    }
}
