//! Distance kernels: dot product and squared Euclidean distance over f32,
//! with AVX-512F or AVX2+FMA picked at run time (so one binary runs on any
//! x86-64, the Docker image too) and a portable fallback. Each SIMD kernel
//! keeps four independent accumulators, so the FMA latency is hidden, and
//! sums them once at the end.
//!
//! `CHOREO_KERNEL=portable|avx2|avx512` forces one (benchmarks, tests); an
//! unsupported choice falls back to the best the CPU has.

use std::sync::OnceLock;

/// Which kernel family runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    Portable,
    Avx2,
    Avx512,
}

impl Kernel {
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Portable => "portable",
            Kernel::Avx2 => "avx2+fma",
            Kernel::Avx512 => "avx512f",
        }
    }

    /// Whether this CPU can run it.
    pub fn supported(self) -> bool {
        match self {
            Kernel::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
            }
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The best kernel this CPU runs.
    pub fn best() -> Kernel {
        [Kernel::Avx512, Kernel::Avx2]
            .into_iter()
            .find(|k| k.supported())
            .unwrap_or(Kernel::Portable)
    }

    /// Dot product with this kernel (panics if unsupported: check first).
    pub fn dot(self, a: &[f32], b: &[f32]) -> f32 {
        assert!(self.supported(), "{} is not supported here", self.name());
        let n = a.len().min(b.len());
        let (a, b) = (&a[..n], &b[..n]);
        match self {
            Kernel::Portable => portable::dot(a, b),
            // SAFETY: the CPU features were checked just above.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => unsafe { x86::dot_avx2(a, b) },
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => unsafe { x86::dot_avx512(a, b) },
            #[cfg(not(target_arch = "x86_64"))]
            _ => portable::dot(a, b),
        }
    }

    /// Squared Euclidean distance with this kernel.
    pub fn l2sq(self, a: &[f32], b: &[f32]) -> f32 {
        assert!(self.supported(), "{} is not supported here", self.name());
        let n = a.len().min(b.len());
        let (a, b) = (&a[..n], &b[..n]);
        match self {
            Kernel::Portable => portable::l2sq(a, b),
            // SAFETY: the CPU features were checked just above.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => unsafe { x86::l2sq_avx2(a, b) },
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => unsafe { x86::l2sq_avx512(a, b) },
            #[cfg(not(target_arch = "x86_64"))]
            _ => portable::l2sq(a, b),
        }
    }
}

type Fn2 = fn(&[f32], &[f32]) -> f32;
type FnHalf = fn(&[f32], &[u16]) -> f32;

struct Chosen {
    kernel: Kernel,
    dot: Fn2,
    l2sq: Fn2,
    dot_f16: FnHalf,
    l2sq_f16: FnHalf,
}

impl Kernel {
    /// The (dot, squared distance) pair of this family against half-float
    /// vectors (the AVX2 family needs F16C too, else portable).
    fn half_fns(self) -> (FnHalf, FnHalf) {
        match self {
            // SAFETY (both arms): the family is supported on this CPU.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => (
                |a, b| unsafe { half_float::x86::dot_avx512(a, b) },
                |a, b| unsafe { half_float::x86::l2sq_avx512(a, b) },
            ),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 if half_float::x86::avx2_f16c() => (
                |a, b| unsafe { half_float::x86::dot_avx2(a, b) },
                |a, b| unsafe { half_float::x86::l2sq_avx2(a, b) },
            ),
            _ => (half_float::portable::dot, half_float::portable::l2sq),
        }
    }

    /// Dot product of an f32 vector with a half-float one, this family.
    pub fn dot_f16(self, a: &[f32], b: &[u16]) -> f32 {
        assert!(self.supported(), "{} is not supported here", self.name());
        let n = a.len().min(b.len());
        (self.half_fns().0)(&a[..n], &b[..n])
    }

    /// Squared distance of an f32 vector to a half-float one, this family.
    pub fn l2sq_f16(self, a: &[f32], b: &[u16]) -> f32 {
        assert!(self.supported(), "{} is not supported here", self.name());
        let n = a.len().min(b.len());
        (self.half_fns().1)(&a[..n], &b[..n])
    }
}

fn chosen() -> &'static Chosen {
    static CHOSEN: OnceLock<Chosen> = OnceLock::new();
    CHOSEN.get_or_init(|| {
        let forced = match std::env::var("CHOREO_KERNEL").as_deref() {
            Ok("portable") => Some(Kernel::Portable),
            Ok("avx2") => Some(Kernel::Avx2),
            Ok("avx512") => Some(Kernel::Avx512),
            _ => None,
        };
        let kernel = forced
            .filter(|k| k.supported())
            .unwrap_or_else(Kernel::best);
        let (dot, l2sq): (Fn2, Fn2) = match kernel {
            Kernel::Portable => (portable::dot, portable::l2sq),
            // SAFETY (both arms): `kernel` is supported on this CPU.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => (
                |a, b| unsafe { x86::dot_avx2(a, b) },
                |a, b| unsafe { x86::l2sq_avx2(a, b) },
            ),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => (
                |a, b| unsafe { x86::dot_avx512(a, b) },
                |a, b| unsafe { x86::l2sq_avx512(a, b) },
            ),
            #[cfg(not(target_arch = "x86_64"))]
            _ => (portable::dot, portable::l2sq),
        };
        let (dot_f16, l2sq_f16) = kernel.half_fns();
        Chosen {
            kernel,
            dot,
            l2sq,
            dot_f16,
            l2sq_f16,
        }
    })
}

/// The kernel in use in this process.
pub fn active() -> Kernel {
    chosen().kernel
}

/// Dot product of the common prefix of `a` and `b`.
#[inline]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    (chosen().dot)(&a[..n], &b[..n])
}

/// Squared Euclidean distance of the common prefix of `a` and `b`.
#[inline]
pub fn l2sq(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    (chosen().l2sq)(&a[..n], &b[..n])
}

/// Dot product of `a` with the half-float vector `b` (common prefix).
#[inline]
pub fn dot_f16(a: &[f32], b: &[u16]) -> f32 {
    let n = a.len().min(b.len());
    (chosen().dot_f16)(&a[..n], &b[..n])
}

/// Squared Euclidean distance of `a` to the half-float vector `b`.
#[inline]
pub fn l2sq_f16(a: &[f32], b: &[u16]) -> f32 {
    let n = a.len().min(b.len());
    (chosen().l2sq_f16)(&a[..n], &b[..n])
}

/// Dot products (or, with `l2`, squared distances) of `a` with each of
/// `bs`, into `out`. With AVX-512 four vectors are taken in one pass over
/// `a`: each load of `a` feeds four FMAs, so the kernel issues 1.25 loads
/// per FMA instead of 2 (a graph walk scores a node's new neighbours
/// together). Other kernels score them one by one.
pub fn batch(a: &[f32], bs: &[&[f32]], l2: bool, out: &mut Vec<f32>) {
    out.clear();
    let c = chosen();
    let one = if l2 { c.l2sq } else { c.dot };
    #[cfg(target_arch = "x86_64")]
    if c.kernel == Kernel::Avx512 && bs.iter().all(|b| b.len() == a.len()) {
        // SAFETY: AVX-512F was chosen, so the CPU has it; equal lengths.
        let pass = |four: [&[f32]; 4]| unsafe {
            if l2 {
                x86::l2sq4_avx512(a, four)
            } else {
                x86::dot4_avx512(a, four)
            }
        };
        let mut chunks = bs.chunks_exact(4);
        for four in chunks.by_ref() {
            out.extend(pass([four[0], four[1], four[2], four[3]]));
        }
        match chunks.remainder() {
            [] => {}
            [b] => out.push(one(a, b)),
            // Two or three left: one four-wide pass, the last repeated.
            rest => {
                let last = rest[rest.len() - 1];
                let r = pass(std::array::from_fn(|i| {
                    rest.get(i).copied().unwrap_or(last)
                }));
                out.extend_from_slice(&r[..rest.len()]);
            }
        }
        return;
    }
    out.extend(bs.iter().map(|b| {
        let n = a.len().min(b.len());
        one(&a[..n], &b[..n])
    }));
}

mod portable {
    /// Eight partial sums, so the compiler can vectorise for the baseline
    /// target (SSE2) without reassociating.
    pub fn dot(a: &[f32], b: &[f32]) -> f32 {
        let mut acc = [0f32; 8];
        let chunks = a.len() / 8;
        for i in 0..chunks {
            for k in 0..8 {
                acc[k] += a[i * 8 + k] * b[i * 8 + k];
            }
        }
        let mut s: f32 = acc.iter().sum();
        for i in chunks * 8..a.len() {
            s += a[i] * b[i];
        }
        s
    }

    pub fn l2sq(a: &[f32], b: &[f32]) -> f32 {
        let mut acc = [0f32; 8];
        let chunks = a.len() / 8;
        for i in 0..chunks {
            for k in 0..8 {
                let d = a[i * 8 + k] - b[i * 8 + k];
                acc[k] += d * d;
            }
        }
        let mut s: f32 = acc.iter().sum();
        for i in chunks * 8..a.len() {
            let d = a[i] - b[i];
            s += d * d;
        }
        s
    }
}

/// One SIMD kernel over an f32 slice and a slice of stored elements
/// (f32, or half-float bits): four independent accumulators of `$w` lanes,
/// `$step(x, y, acc)` per register, the horizontal sum, and the portable
/// kernel `$tail` for the last `< $w` elements. `$load(p)` reads `$w`
/// stored elements as f32 lanes. Used for every (family, type, distance).
#[cfg(target_arch = "x86_64")]
macro_rules! simd_kernel {
    (
        $(#[$doc:meta])* $name:ident, $feat:literal, $t:ty, $w:literal,
        $zero:ident, $loadf:ident, $load:expr, $add:ident, $hsum:expr,
        |$x:ident, $y:ident, $acc:ident| $step:expr, $tail:path
    ) => {
        $(#[$doc])*
        #[target_feature(enable = $feat)]
        pub unsafe fn $name(a: &[f32], b: &[$t]) -> f32 {
            let n = a.len();
            let (pa, pb) = (a.as_ptr(), b.as_ptr());
            let mut acc = [$zero(); 4];
            let mut i = 0;
            while i + 4 * $w <= n {
                for (k, slot) in acc.iter_mut().enumerate() {
                    let ($x, $y, $acc) = ($loadf(pa.add(i + $w * k)), $load(pb.add(i + $w * k)), *slot);
                    *slot = $step;
                }
                i += 4 * $w;
            }
            while i + $w <= n {
                let ($x, $y, $acc) = ($loadf(pa.add(i)), $load(pb.add(i)), acc[0]);
                acc[0] = $step;
                i += $w;
            }
            let s = $hsum($add($add(acc[0], acc[1]), $add(acc[2], acc[3])));
            s + $tail(&a[i..], &b[i..])
        }
    };
}

/// The AVX2+FMA and AVX-512F kernels (dot, squared distance) over one
/// stored element type; `$load8` / `$load16` read it as f32 lanes.
#[cfg(target_arch = "x86_64")]
macro_rules! x86_kernels {
    ($t:ty, $avx2:literal, $load8:expr, $load16:expr, $pdot:path, $pl2:path,
     $dot2:ident, $l22:ident, $dot5:ident, $l25:ident) => {
        simd_kernel!(
            /// # Safety
            /// The CPU has the AVX2 family's features; same lengths.
            $dot2, $avx2, $t, 8, _mm256_setzero_ps, _mm256_loadu_ps, $load8,
            _mm256_add_ps, |v| hsum256(v), |x, y, acc| _mm256_fmadd_ps(x, y, acc), $pdot
        );
        simd_kernel!(
            /// # Safety
            /// The CPU has the AVX2 family's features; same lengths.
            $l22, $avx2, $t, 8, _mm256_setzero_ps, _mm256_loadu_ps, $load8,
            _mm256_add_ps, |v| hsum256(v),
            |x, y, acc| { let d = _mm256_sub_ps(x, y); _mm256_fmadd_ps(d, d, acc) }, $pl2
        );
        simd_kernel!(
            /// # Safety
            /// The CPU has AVX-512F; same lengths.
            $dot5, "avx512f", $t, 16, _mm512_setzero_ps, _mm512_loadu_ps, $load16,
            _mm512_add_ps, |v| _mm512_reduce_add_ps(v),
            |x, y, acc| _mm512_fmadd_ps(x, y, acc), $pdot
        );
        simd_kernel!(
            /// # Safety
            /// The CPU has AVX-512F; same lengths.
            $l25, "avx512f", $t, 16, _mm512_setzero_ps, _mm512_loadu_ps, $load16,
            _mm512_add_ps, |v| _mm512_reduce_add_ps(v),
            |x, y, acc| { let d = _mm512_sub_ps(x, y); _mm512_fmadd_ps(d, d, acc) }, $pl2
        );
    };
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// The eight lanes' sum.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn hsum256(v: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
        _mm_cvtss_f32(s)
    }

    /// Four candidates per pass over `a` (see [`super::batch`]), each
    /// summed exactly as the one-vector AVX-512 kernel sums it (four
    /// accumulators, the same steps, reduction and portable tail), so a
    /// distance is the same bits whichever way it was computed and ties
    /// between equal vectors break the same way everywhere.
    macro_rules! four_kernel {
        ($name:ident, |$x:ident, $y:ident, $acc:ident| $step:expr, $tail:path) => {
            /// # Safety
            /// The CPU has AVX-512F; every `b` as long as `a`.
            #[target_feature(enable = "avx512f")]
            pub unsafe fn $name(a: &[f32], b: [&[f32]; 4]) -> [f32; 4] {
                let n = a.len();
                let pa = a.as_ptr();
                let pb = b.map(|b| b.as_ptr());
                let mut acc = [[_mm512_setzero_ps(); 4]; 4];
                let mut i = 0;
                while i + 64 <= n {
                    for k in 0..4 {
                        let xk = _mm512_loadu_ps(pa.add(i + 16 * k));
                        for c in 0..4 {
                            let ($x, $y, $acc) =
                                (xk, _mm512_loadu_ps(pb[c].add(i + 16 * k)), acc[c][k]);
                            acc[c][k] = $step;
                        }
                    }
                    i += 64;
                }
                while i + 16 <= n {
                    let x0 = _mm512_loadu_ps(pa.add(i));
                    for c in 0..4 {
                        let ($x, $y, $acc) = (x0, _mm512_loadu_ps(pb[c].add(i)), acc[c][0]);
                        acc[c][0] = $step;
                    }
                    i += 16;
                }
                std::array::from_fn(|c| {
                    let a4 = acc[c];
                    let s = _mm512_reduce_add_ps(_mm512_add_ps(
                        _mm512_add_ps(a4[0], a4[1]),
                        _mm512_add_ps(a4[2], a4[3]),
                    ));
                    s + $tail(&a[i..], &b[c][i..n])
                })
            }
        };
    }

    four_kernel!(
        dot4_avx512,
        |x, y, acc| _mm512_fmadd_ps(x, y, acc),
        super::portable::dot
    );
    four_kernel!(
        l2sq4_avx512,
        |x, y, acc| {
            let d = _mm512_sub_ps(x, y);
            _mm512_fmadd_ps(d, d, acc)
        },
        super::portable::l2sq
    );

    x86_kernels!(
        f32,
        "avx2,fma",
        |p| _mm256_loadu_ps(p),
        |p| _mm512_loadu_ps(p),
        super::portable::dot,
        super::portable::l2sq,
        dot_avx2,
        l2sq_avx2,
        dot_avx512,
        l2sq_avx512
    );
}

// After the kernel macros: the half-float kernels use them.
pub mod half_float;

#[cfg(test)]
mod tests {
    use super::*;

    /// The batch scoring (four vectors per pass with AVX-512) equals an f64
    /// sum for dot and squared distance, at lengths with and without tails,
    /// and for batches that are not a multiple of four.
    #[test]
    fn batch_agrees_with_f64() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        for n in [0, 1, 31, 32, 33, 100, 1152, 9720] {
            let a: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            for m in [1, 3, 4, 7, 9] {
                let bs: Vec<Vec<f32>> = (0..m)
                    .map(|_| (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect())
                    .collect();
                let refs: Vec<&[f32]> = bs.iter().map(|b| b.as_slice()).collect();
                for l2 in [false, true] {
                    let mut out = Vec::new();
                    batch(&a, &refs, l2, &mut out);
                    assert_eq!(out.len(), m);
                    // The same bits as one vector at a time.
                    for (b, got) in bs.iter().zip(&out) {
                        let one = if l2 { l2sq(&a, b) } else { dot(&a, b) };
                        assert_eq!(got.to_bits(), one.to_bits(), "n {n} m {m} l2 {l2}");
                    }
                    for (b, got) in bs.iter().zip(&out) {
                        let want: f64 = a
                            .iter()
                            .zip(b)
                            .map(|(x, y)| {
                                let (x, y) = (*x as f64, *y as f64);
                                if l2 {
                                    (x - y) * (x - y)
                                } else {
                                    x * y
                                }
                            })
                            .sum();
                        assert!(
                            (*got as f64 - want).abs() < 1e-4 * (1.0 + want.abs()),
                            "n {n} m {m} l2 {l2}: {got} vs {want}"
                        );
                    }
                }
            }
        }
    }

    /// Every kernel this CPU runs agrees with an f64 sum, at every length
    /// from 0 to 200 (all tails) and at the embeddings' 1,152.
    #[test]
    fn kernels_agree_with_f64() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let lens: Vec<usize> = (0..=200).chain([1152, 2048 + 7]).collect();
        for n in lens {
            let a: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let b: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let d64: f64 = a.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            let l64: f64 = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
                .sum();
            for k in [Kernel::Portable, Kernel::Avx2, Kernel::Avx512] {
                if !k.supported() {
                    eprintln!("{} not supported on this CPU: not checked", k.name());
                    continue;
                }
                let tol = 1e-5 * (n as f64).max(1.0);
                assert!(
                    (k.dot(&a, &b) as f64 - d64).abs() < tol,
                    "{} dot n={n}",
                    k.name()
                );
                assert!(
                    (k.l2sq(&a, &b) as f64 - l64).abs() < tol,
                    "{} l2sq n={n}",
                    k.name()
                );
            }
        }
        assert!(active().supported());
    }

    /// The half-float kernels agree with an f64 sum over the decoded
    /// halves, every tail length, every family this CPU runs.
    #[test]
    fn half_kernels_agree_with_f64() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(4);
        let lens: Vec<usize> = (0..=150).chain([1152, 2048 + 7]).collect();
        let mut wide = Vec::new();
        for n in lens {
            let a: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let b: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let h = half_float::encode(&b);
            half_float::decode(&h, &mut wide);
            // Rounding to half: relative error at most 2^-11.
            for (x, y) in b.iter().zip(&wide) {
                assert!((x - y).abs() <= x.abs() * 4.9e-4 + 6.0e-8, "{x} -> {y}");
            }
            let d64: f64 = a
                .iter()
                .zip(&wide)
                .map(|(x, y)| *x as f64 * *y as f64)
                .sum();
            let l64: f64 = a
                .iter()
                .zip(&wide)
                .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
                .sum();
            for k in [Kernel::Portable, Kernel::Avx2, Kernel::Avx512] {
                if !k.supported() {
                    continue;
                }
                let tol = 1e-5 * (n as f64).max(1.0);
                assert!(
                    (k.dot_f16(&a, &h) as f64 - d64).abs() < tol,
                    "{} dot_f16 n={n}",
                    k.name()
                );
                assert!(
                    (k.l2sq_f16(&a, &h) as f64 - l64).abs() < tol,
                    "{} l2sq_f16 n={n}",
                    k.name()
                );
            }
        }
        assert_eq!(
            half_float::encode(&[1e6, -1e6]),
            half_float::encode(&[65504.0, -65504.0])
        );
    }
}
