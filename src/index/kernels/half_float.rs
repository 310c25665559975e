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
    use super::super::x86::hsum256;
    use std::arch::x86_64::*;

    /// Whether the AVX2 family's half kernels run here (F16C as well).
    pub fn avx2_f16c() -> bool {
        std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
            && std::arch::is_x86_feature_detected!("f16c")
    }

    x86_kernels!(
        u16,
        "avx2,fma,f16c",
        |p: *const u16| _mm256_cvtph_ps(_mm_loadu_si128(p as *const __m128i)),
        |p: *const u16| _mm512_cvtph_ps(_mm256_loadu_si256(p as *const __m256i)),
        super::portable::dot,
        super::portable::l2sq,
        dot_avx2,
        l2sq_avx2,
        dot_avx512,
        l2sq_avx512
    );
}
