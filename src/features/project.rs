//! One blocked matrix product for the DCT and PCA embeddings: every one of a
//! window's 72 channels (128 samples) times a 128 × 16 basis, with an
//! optional per-output offset (the PCA mean folded out: `C·(x − μ) = C·x −
//! C·μ`). Eight channels at a time keep eight 16-wide accumulators live;
//! the basis row is loaded once per sample and each sample broadcast, so
//! the inner loop is pure FMAs. AVX-512F and AVX2+FMA kernels are written
//! with intrinsics (left to itself, LLVM vectorised AVX-512 across channels
//! with gathers, 8× slower than portable), picked at run time
//! ([`crate::index::kernels::Kernel`]); the portable one is plain Rust.

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
            _ => apply_block(&self.basis_t, &self.offset, win, &mut out),
        }
        out
    }
}

/// AVX-512: one 16-lane register per channel, eight channels a block.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn apply_avx512(b: &[f32], off: &[f32; COEFFS], win: &[f32], out: &mut [f32]) {
    use std::arch::x86_64::*;
    const J: usize = 8;
    debug_assert!(b.len() == WINDOW * COEFFS && win.len() == CHANNELS * WINDOW);
    let o = _mm512_loadu_ps(off.as_ptr());
    prefetch_block(win, 0, J);
    for c0 in (0..CHANNELS).step_by(J) {
        let mut acc = [o; J];
        let x = win.as_ptr().add(c0 * WINDOW);
        for t in 0..WINDOW {
            prefetch_next(win, c0 + J, J, t);
            let bt = _mm512_loadu_ps(b.as_ptr().add(t * COEFFS));
            for (j, a) in acc.iter_mut().enumerate() {
                *a = _mm512_fmadd_ps(_mm512_set1_ps(*x.add(j * WINDOW + t)), bt, *a);
            }
        }
        for (j, a) in acc.iter().enumerate() {
            _mm512_storeu_ps(out.as_mut_ptr().add((c0 + j) * COEFFS), *a);
        }
    }
}

/// AVX2: two 8-lane registers per channel, six channels a block (twelve
/// accumulators, the basis row and a broadcast fit the sixteen registers).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn apply_avx2(b: &[f32], off: &[f32; COEFFS], win: &[f32], out: &mut [f32]) {
    use std::arch::x86_64::*;
    const J: usize = 6;
    debug_assert!(b.len() == WINDOW * COEFFS && win.len() == CHANNELS * WINDOW);
    let (o0, o1) = (
        _mm256_loadu_ps(off.as_ptr()),
        _mm256_loadu_ps(off.as_ptr().add(8)),
    );
    prefetch_block(win, 0, J);
    for c0 in (0..CHANNELS).step_by(J) {
        let mut lo = [o0; J];
        let mut hi = [o1; J];
        let x = win.as_ptr().add(c0 * WINDOW);
        for t in 0..WINDOW {
            prefetch_next(win, c0 + J, J, t);
            let b0 = _mm256_loadu_ps(b.as_ptr().add(t * COEFFS));
            let b1 = _mm256_loadu_ps(b.as_ptr().add(t * COEFFS + 8));
            for j in 0..J {
                let v = _mm256_set1_ps(*x.add(j * WINDOW + t));
                lo[j] = _mm256_fmadd_ps(v, b0, lo[j]);
                hi[j] = _mm256_fmadd_ps(v, b1, hi[j]);
            }
        }
        for j in 0..J {
            let p = out.as_mut_ptr().add((c0 + j) * COEFFS);
            _mm256_storeu_ps(p, lo[j]);
            _mm256_storeu_ps(p.add(8), hi[j]);
        }
    }
}

/// Floats in a cache line.
const LINE: usize = 16;

/// Ask for the cache lines of channels `c0..c0 + j` at once (the first
/// block of a window).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn prefetch_block(win: &[f32], c0: usize, j: usize) {
    use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
    let lines = &win[(c0 * WINDOW).min(win.len())..((c0 + j) * WINDOW).min(win.len())];
    for l in lines.chunks(LINE) {
        // SAFETY: a prefetch of memory inside the slice.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(l.as_ptr() as *const i8) };
    }
}

/// While the block before is multiplied, one line of the next block
/// (channels `c0..c0 + j`) every other sample. The window is channel-major,
/// so a block reads `j` rows of one 4 KB page side by side, a pattern the
/// hardware's per-page stream prefetcher does not follow: from memory the
/// product waited on every row (measured in `choreo bench embed`).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn prefetch_next(win: &[f32], c0: usize, j: usize, t: usize) {
    use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
    if t % 2 == 0 && t / 2 < j * WINDOW / LINE {
        if let Some(l) = win.get(c0 * WINDOW + t / 2 * LINE) {
            // SAFETY: a prefetch of an element of the slice.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(l as *const f32 as *const i8) };
        }
    }
}

/// Channels per block: eight accumulator rows of 16 lanes.
const BLOCK: usize = 8;

/// The portable kernel (SSE2 on the baseline target: vectorised over the
/// 16 coefficients).
fn apply_block(b: &[f32], off: &[f32; COEFFS], win: &[f32], out: &mut [f32]) {
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
                    acc[j][k] += x * bt[k];
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
            apply_block(&p.basis_t, &p.offset, &win, &mut portable);
            #[cfg(target_arch = "x86_64")]
            for k in [Kernel::Avx2, Kernel::Avx512] {
                if !k.supported() {
                    continue;
                }
                let mut simd = vec![0f32; CHANNELS * COEFFS];
                // SAFETY: checked just above.
                unsafe {
                    match k {
                        Kernel::Avx2 => apply_avx2(&p.basis_t, &p.offset, &win, &mut simd),
                        _ => apply_avx512(&p.basis_t, &p.offset, &win, &mut simd),
                    }
                }
                for (i, w) in want.iter().enumerate() {
                    assert!((simd[i] as f64 - w).abs() < 1e-3, "{} {i}", k.name());
                }
            }
            for (i, w) in want.iter().enumerate() {
                assert!((got[i] as f64 - w).abs() < 1e-3, "{i}: {} vs {w}", got[i]);
                assert!((portable[i] as f64 - w).abs() < 1e-3, "{i}");
            }
        }
    }
}
