//! One blocked matrix product for the DCT and PCA embeddings: every one of a
//! window's 72 channels (128 samples) times a 128 × 16 basis, with an
//! optional per-output offset (the PCA mean folded out: `C·(x − μ) = C·x −
//! C·μ`). Eight channels at a time keep eight 16-wide accumulators live;
//! the basis row is loaded once per sample and each sample broadcast, so
//! the inner loop is pure FMAs. The same code is compiled for AVX-512F,
//! AVX2+FMA and the portable baseline, picked at run time
//! ([`crate::index::kernels::Kernel`]).

use super::{CHANNELS, COEFFS, WINDOW};
use crate::index::kernels::{self, Kernel};

/// A 128 × 16 basis stored sample-major (`[t][k]`), and an offset per
/// output coefficient.
#[derive(Clone, Debug)]
pub struct Projection {
    basis_t: Vec<f32>,
    offset: [f32; COEFFS],
}

impl Projection {
    /// From coefficient-major rows (`[k][t]`, the usual layout: DCT
    /// functions, PCA components) and the input mean to fold out (zero for
    /// the DCT).
    pub fn new(rows: &[f32], mean: Option<&[f32]>) -> Projection {
        assert_eq!(rows.len(), COEFFS * WINDOW, "basis shape");
        let mut basis_t = vec![0f32; WINDOW * COEFFS];
        for k in 0..COEFFS {
            for t in 0..WINDOW {
                basis_t[t * COEFFS + k] = rows[k * WINDOW + t];
            }
        }
        let mut offset = [0f32; COEFFS];
        if let Some(mu) = mean {
            for (k, o) in offset.iter_mut().enumerate() {
                *o = -(0..WINDOW)
                    .map(|t| rows[k * WINDOW + t] as f64 * mu[t] as f64)
                    .sum::<f64>() as f32;
            }
        }
        Projection { basis_t, offset }
    }

    /// Project one window (`[72][128]`, channel-major) to `[72][16]`.
    pub fn apply(&self, win: &[f32]) -> Vec<f32> {
        assert_eq!(win.len(), CHANNELS * WINDOW, "window shape");
        let mut out = vec![0f32; CHANNELS * COEFFS];
        match kernels::active() {
            // SAFETY: `active` only picks kernels the CPU supports.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => unsafe { apply_avx512(&self.basis_t, &self.offset, win, &mut out) },
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => unsafe { apply_avx2(&self.basis_t, &self.offset, win, &mut out) },
            _ => apply_block::<false>(&self.basis_t, &self.offset, win, &mut out),
        }
        out
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
unsafe fn apply_avx512(b: &[f32], off: &[f32; COEFFS], win: &[f32], out: &mut [f32]) {
    apply_block::<true>(b, off, win, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn apply_avx2(b: &[f32], off: &[f32; COEFFS], win: &[f32], out: &mut [f32]) {
    apply_block::<true>(b, off, win, out)
}

/// Channels per block: eight accumulator rows of 16 lanes.
const BLOCK: usize = 8;

#[inline(always)]
fn apply_block<const FMA: bool>(b: &[f32], off: &[f32; COEFFS], win: &[f32], out: &mut [f32]) {
    let b: &[f32; WINDOW * COEFFS] = b.try_into().expect("basis shape");
    for c0 in (0..CHANNELS).step_by(BLOCK) {
        let mut acc = [*off; BLOCK];
        let rows: [&[f32; WINDOW]; BLOCK] = std::array::from_fn(|j| {
            win[(c0 + j) * WINDOW..(c0 + j + 1) * WINDOW]
                .try_into()
                .expect("window row")
        });
        for t in 0..WINDOW {
            let bt: &[f32; COEFFS] = b[t * COEFFS..(t + 1) * COEFFS].try_into().expect("row");
            for j in 0..BLOCK {
                let x = rows[j][t];
                for k in 0..COEFFS {
                    acc[j][k] = if FMA {
                        x.mul_add(bt[k], acc[j][k])
                    } else {
                        acc[j][k] + x * bt[k]
                    };
                }
            }
        }
        for (j, a) in acc.iter().enumerate() {
            out[(c0 + j) * COEFFS..(c0 + j + 1) * COEFFS].copy_from_slice(a);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every kernel equals the plain f64 product, mean folded or not.
    #[test]
    fn projection_matches_f64() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let rows: Vec<f32> = (0..COEFFS * WINDOW)
            .map(|_| rng.gen_range(-0.2..0.2))
            .collect();
        let mean: Vec<f32> = (0..WINDOW).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let win: Vec<f32> = (0..CHANNELS * WINDOW)
            .map(|_| rng.gen_range(-3.0..3.0))
            .collect();
        for mu in [None, Some(mean.as_slice())] {
            let p = Projection::new(&rows, mu);
            let want: Vec<f64> = (0..CHANNELS)
                .flat_map(|c| {
                    let (rows, win) = (&rows, &win);
                    (0..COEFFS).map(move |k| {
                        (0..WINDOW)
                            .map(|t| {
                                rows[k * WINDOW + t] as f64
                                    * (win[c * WINDOW + t] as f64 - mu.map_or(0.0, |m| m[t] as f64))
                            })
                            .sum::<f64>()
                    })
                })
                .collect();
            let got = p.apply(&win);
            let mut portable = vec![0f32; CHANNELS * COEFFS];
            apply_block::<false>(&p.basis_t, &p.offset, &win, &mut portable);
            for (i, w) in want.iter().enumerate() {
                assert!((got[i] as f64 - w).abs() < 1e-3, "{i}: {} vs {w}", got[i]);
                assert!((portable[i] as f64 - w).abs() < 1e-3, "{i}");
            }
        }
    }
}
