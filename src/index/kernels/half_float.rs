//! Distances between an f32 query and a vector stored as IEEE half floats
//! (`--vector-dtype f16`: half the memory and the memory traffic of a
//! search). The stored halves are widened in registers (F16C's `vcvtph2ps`,
//! part of AVX-512F, and beside AVX2 on every CPU that has it), so the
//! arithmetic stays f32 with the same four accumulators as the f32
//! kernels. Portable fallback through the `half` crate.

/// Half-float bits of `v`, rounded to nearest; magnitudes beyond the
/// format's range (65,504) saturate instead of becoming infinite.
pub fn encode(v: &[f32]) -> Vec<u16> {
    v.iter()
        .map(|&x| ::half::f16::from_f32(x.clamp(-65504.0, 65504.0)).to_bits())
        .collect()
}

/// The f32 values of half-float bits (the `half` crate's slice
/// conversion: F16C when the CPU has it).
pub fn decode(h: &[u16], out: &mut Vec<f32>) {
    use ::half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};
    out.clear();
    out.resize(h.len(), 0.0);
    h.reinterpret_cast::<::half::f16>()
        .convert_to_f32_slice(out);
}

pub(super) mod portable {
    pub fn dot(a: &[f32], b: &[u16]) -> f32 {
        let mut acc = [0f32; 8];
        let chunks = a.len() / 8;
        for i in 0..chunks {
            for k in 0..8 {
                acc[k] += a[i * 8 + k] * ::half::f16::from_bits(b[i * 8 + k]).to_f32();
            }
        }
        let mut s: f32 = acc.iter().sum();
        for i in chunks * 8..a.len() {
            s += a[i] * ::half::f16::from_bits(b[i]).to_f32();
        }
        s
    }

    pub fn l2sq(a: &[f32], b: &[u16]) -> f32 {
        let mut acc = [0f32; 8];
        let chunks = a.len() / 8;
        for i in 0..chunks {
            for k in 0..8 {
                let d = a[i * 8 + k] - ::half::f16::from_bits(b[i * 8 + k]).to_f32();
                acc[k] += d * d;
            }
        }
        let mut s: f32 = acc.iter().sum();
        for i in chunks * 8..a.len() {
            let d = a[i] - ::half::f16::from_bits(b[i]).to_f32();
            s += d * d;
        }
        s
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod x86 {
    use std::arch::x86_64::*;

    /// Whether the AVX2 family's half kernels run here (F16C as well).
    pub fn avx2_f16c() -> bool {
        std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
            && std::arch::is_x86_feature_detected!("f16c")
    }

    #[target_feature(enable = "avx2,fma,f16c")]
    unsafe fn hsum256(v: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps(s, s, 1));
        _mm_cvtss_f32(s)
    }

    /// Eight halves from `p`, widened.
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    unsafe fn load8(p: *const u16) -> __m256 {
        _mm256_cvtph_ps(_mm_loadu_si128(p as *const __m128i))
    }

    /// Sixteen halves from `p`, widened.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn load16(p: *const u16) -> __m512 {
        _mm512_cvtph_ps(_mm256_loadu_si256(p as *const __m256i))
    }

    /// # Safety
    /// The CPU has AVX2, FMA and F16C; `a` and `b` have the same length.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub unsafe fn dot_avx2(a: &[f32], b: &[u16]) -> f32 {
        let n = a.len();
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        let mut acc = [_mm256_setzero_ps(); 4];
        let mut i = 0;
        while i + 32 <= n {
            for (k, acc) in acc.iter_mut().enumerate() {
                let x = _mm256_loadu_ps(pa.add(i + 8 * k));
                *acc = _mm256_fmadd_ps(x, load8(pb.add(i + 8 * k)), *acc);
            }
            i += 32;
        }
        while i + 8 <= n {
            acc[0] = _mm256_fmadd_ps(_mm256_loadu_ps(pa.add(i)), load8(pb.add(i)), acc[0]);
            i += 8;
        }
        let mut s = hsum256(_mm256_add_ps(
            _mm256_add_ps(acc[0], acc[1]),
            _mm256_add_ps(acc[2], acc[3]),
        ));
        s += super::portable::dot(&a[i..], &b[i..]);
        s
    }

    /// # Safety
    /// The CPU has AVX2, FMA and F16C; `a` and `b` have the same length.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub unsafe fn l2sq_avx2(a: &[f32], b: &[u16]) -> f32 {
        let n = a.len();
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        let mut acc = [_mm256_setzero_ps(); 4];
        let mut i = 0;
        while i + 32 <= n {
            for (k, acc) in acc.iter_mut().enumerate() {
                let d = _mm256_sub_ps(_mm256_loadu_ps(pa.add(i + 8 * k)), load8(pb.add(i + 8 * k)));
                *acc = _mm256_fmadd_ps(d, d, *acc);
            }
            i += 32;
        }
        while i + 8 <= n {
            let d = _mm256_sub_ps(_mm256_loadu_ps(pa.add(i)), load8(pb.add(i)));
            acc[0] = _mm256_fmadd_ps(d, d, acc[0]);
            i += 8;
        }
        let mut s = hsum256(_mm256_add_ps(
            _mm256_add_ps(acc[0], acc[1]),
            _mm256_add_ps(acc[2], acc[3]),
        ));
        s += super::portable::l2sq(&a[i..], &b[i..]);
        s
    }

    /// # Safety
    /// The CPU has AVX-512F; `a` and `b` have the same length.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn dot_avx512(a: &[f32], b: &[u16]) -> f32 {
        let n = a.len();
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        let mut acc = [_mm512_setzero_ps(); 4];
        let mut i = 0;
        while i + 64 <= n {
            for (k, acc) in acc.iter_mut().enumerate() {
                let x = _mm512_loadu_ps(pa.add(i + 16 * k));
                *acc = _mm512_fmadd_ps(x, load16(pb.add(i + 16 * k)), *acc);
            }
            i += 64;
        }
        while i + 16 <= n {
            acc[0] = _mm512_fmadd_ps(_mm512_loadu_ps(pa.add(i)), load16(pb.add(i)), acc[0]);
            i += 16;
        }
        let s = _mm512_reduce_add_ps(_mm512_add_ps(
            _mm512_add_ps(acc[0], acc[1]),
            _mm512_add_ps(acc[2], acc[3]),
        ));
        s + super::portable::dot(&a[i..], &b[i..])
    }

    /// # Safety
    /// The CPU has AVX-512F; `a` and `b` have the same length.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn l2sq_avx512(a: &[f32], b: &[u16]) -> f32 {
        let n = a.len();
        let (pa, pb) = (a.as_ptr(), b.as_ptr());
        let mut acc = [_mm512_setzero_ps(); 4];
        let mut i = 0;
        while i + 64 <= n {
            for (k, acc) in acc.iter_mut().enumerate() {
                let d = _mm512_sub_ps(
                    _mm512_loadu_ps(pa.add(i + 16 * k)),
                    load16(pb.add(i + 16 * k)),
                );
                *acc = _mm512_fmadd_ps(d, d, *acc);
            }
            i += 64;
        }
        while i + 16 <= n {
            let d = _mm512_sub_ps(_mm512_loadu_ps(pa.add(i)), load16(pb.add(i)));
            acc[0] = _mm512_fmadd_ps(d, d, acc[0]);
            i += 16;
        }
        let s = _mm512_reduce_add_ps(_mm512_add_ps(
            _mm512_add_ps(acc[0], acc[1]),
            _mm512_add_ps(acc[2], acc[3]),
        ));
        s + super::portable::l2sq(&a[i..], &b[i..])
    }
}
