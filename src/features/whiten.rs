//! Sequence whitening: a linear map fitted on an archive's windows with no
//! labels, only which windows come from the same sequence. It keeps the
//! directions along which sequences differ from one another, measured in
//! units of how much a sequence varies within itself (the LDA directions
//! with the sequence as the class):
//!
//! - `Sw` = within-sequence scatter, `Sb` = between-sequence scatter (each
//!   sequence's mean, weighted by its window count), both per window;
//! - `Sw` is shrunk toward `tr(Sw)/d · I` (so it is invertible with fewer
//!   windows than dimensions);
//! - the directions `p` maximise `pᵀ Sb p / pᵀ Sw p`: with `Sw = L Lᵀ`
//!   (Cholesky) and `A = L⁻¹ M` (`M` the weighted, centred sequence means,
//!   `d × S`), they are `p = L⁻ᵀ A u / √λ` for the eigenpairs `(λ, u)` of
//!   the small `S × S` matrix `AᵀA` (`Sb = M Mᵀ` has rank below `S`), and
//!   `pᵀ Sw p = 1`.
//!
//! A window's whitened vector is `Pᵀ (x − μ)`. Used by `choreo eval query
//! --whiten K` to measure what such a map is worth to each embedding.

use super::pca::jacobi_eigen;
use std::collections::BTreeMap;

/// A fitted sequence whitening: the mean and `k` directions (`d` each).
#[derive(Clone, Debug)]
pub struct Whitening {
    pub mean: Vec<f64>,
    pub directions: Vec<Vec<f64>>,
    /// The generalised eigenvalue of each direction (between / within).
    pub ratios: Vec<f64>,
}

impl Whitening {
    /// Fits on `vectors` grouped by `sequence`, keeping at most `k`
    /// directions (fewer when there are fewer sequences). `shrink` in
    /// [0, 1) mixes `Sw` with its scaled identity. `None` without two
    /// sequences or with vectors of unequal length.
    pub fn fit(vectors: &[&[f32]], sequence: &[usize], k: usize, shrink: f64) -> Option<Whitening> {
        let n = vectors.len();
        let d = vectors.first()?.len();
        if n < 2 || vectors.iter().any(|v| v.len() != d) || sequence.len() != n {
            return None;
        }
        let mut groups: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (i, &s) in sequence.iter().enumerate() {
            groups.entry(s).or_default().push(i);
        }
        let s_count = groups.len();
        if s_count < 2 {
            return None;
        }
        let mut mean = vec![0f64; d];
        for v in vectors {
            for (m, x) in mean.iter_mut().zip(*v) {
                *m += *x as f64 / n as f64;
            }
        }
        // Within scatter (upper triangle, then mirrored) and weighted means.
        let mut sw = vec![0f64; d * d];
        let mut means = vec![0f64; d * s_count]; // column-major d × S
        let mut centred = vec![0f64; d];
        for (col, idx) in groups.values().enumerate() {
            let mut m = vec![0f64; d];
            for &i in idx {
                for (a, x) in m.iter_mut().zip(vectors[i]) {
                    *a += *x as f64 / idx.len() as f64;
                }
            }
            for &i in idx {
                for (c, (x, a)) in centred.iter_mut().zip(vectors[i].iter().zip(&m)) {
                    *c = *x as f64 - a;
                }
                for r in 0..d {
                    let cr = centred[r] / n as f64;
                    if cr == 0.0 {
                        continue;
                    }
                    let row = &mut sw[r * d..(r + 1) * d];
                    for c in r..d {
                        row[c] += cr * centred[c];
                    }
                }
            }
            let w = (idx.len() as f64 / n as f64).sqrt();
            for r in 0..d {
                means[col * d + r] = w * (m[r] - mean[r]);
            }
        }
        for r in 0..d {
            for c in 0..r {
                sw[r * d + c] = sw[c * d + r];
            }
        }
        let trace: f64 = (0..d).map(|i| sw[i * d + i]).sum::<f64>() / d as f64;
        let floor = trace.max(1e-12);
        for (i, x) in sw.iter_mut().enumerate() {
            *x *= 1.0 - shrink;
            if i / d == i % d {
                *x += shrink * floor;
            }
        }
        let l = cholesky(&mut sw, d)?;
        // A = L⁻¹ M, column by column (forward substitution).
        let mut a = means;
        for col in 0..s_count {
            forward(&l, d, &mut a[col * d..(col + 1) * d]);
        }
        // G = AᵀA (S × S).
        let mut g = vec![0f64; s_count * s_count];
        for i in 0..s_count {
            for j in i..s_count {
                let v: f64 = (0..d).map(|r| a[i * d + r] * a[j * d + r]).sum();
                g[i * s_count + j] = v;
                g[j * s_count + i] = v;
            }
        }
        let (vals, vecs) = jacobi_eigen(g, s_count);
        let mut order: Vec<usize> = (0..s_count).collect();
        order.sort_by(|&x, &y| vals[y].total_cmp(&vals[x]));
        let mut directions = Vec::new();
        let mut ratios = Vec::new();
        for &e in order.iter().take(k) {
            let lambda = vals[e];
            if lambda <= 1e-12 {
                break;
            }
            // v = A u / √λ (unit), then p = L⁻ᵀ v.
            let mut v = vec![0f64; d];
            for col in 0..s_count {
                let u = vecs[col * s_count + e] / lambda.sqrt();
                for (x, y) in v.iter_mut().zip(&a[col * d..(col + 1) * d]) {
                    *x += u * y;
                }
            }
            backward_transposed(&l, d, &mut v);
            directions.push(v);
            ratios.push(lambda);
        }
        Some(Whitening {
            mean,
            directions,
            ratios,
        })
    }

    /// The whitened vector of `x`.
    pub fn apply(&self, x: &[f32]) -> Vec<f32> {
        self.directions
            .iter()
            .map(|p| {
                p.iter()
                    .zip(x.iter().zip(&self.mean))
                    .map(|(p, (x, m))| p * (*x as f64 - m))
                    .sum::<f64>() as f32
            })
            .collect()
    }
}

/// In-place Cholesky of a symmetric positive-definite `n × n` matrix
/// (row-major): returns the lower factor `L` (row-major), `None` if not
/// positive definite.
fn cholesky(a: &mut [f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0f64; n * n];
    for j in 0..n {
        let mut s = a[j * n + j];
        for k in 0..j {
            s -= l[j * n + k] * l[j * n + k];
        }
        if s <= 0.0 || !s.is_finite() {
            return None;
        }
        let ljj = s.sqrt();
        l[j * n + j] = ljj;
        for i in j + 1..n {
            let (ri, rj) = (&l[i * n..i * n + j], &l[j * n..j * n + j]);
            let dot: f64 = ri.iter().zip(rj).map(|(x, y)| x * y).sum();
            l[i * n + j] = (a[i * n + j] - dot) / ljj;
        }
    }
    Some(l)
}

/// Solves `L y = b` in place (`L` lower, row-major).
fn forward(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let dot: f64 = (0..i).map(|k| l[i * n + k] * b[k]).sum();
        b[i] = (b[i] - dot) / l[i * n + i];
    }
}

/// Solves `Lᵀ y = b` in place (`L` lower, row-major).
fn backward_transposed(l: &[f64], n: usize, b: &mut [f64]) {
    for i in (0..n).rev() {
        let dot: f64 = (i + 1..n).map(|k| l[k * n + i] * b[k]).sum();
        b[i] = (b[i] - dot) / l[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two sequences apart along x, each spread widely along y: the one
    /// direction is x, scaled so the within-sequence variance along it is
    /// 1, and its ratio is between / within by hand.
    #[test]
    fn finds_the_axis_that_separates_sequences() {
        let mut v: Vec<[f32; 2]> = Vec::new();
        let mut seq = Vec::new();
        for (s, cx) in [(0usize, -1.0f32), (1, 1.0)] {
            for (dx, dy) in [(-0.1, -5.0), (0.1, 5.0), (-0.1, 5.0), (0.1, -5.0)] {
                v.push([cx + dx, dy]);
                seq.push(s);
            }
        }
        let refs: Vec<&[f32]> = v.iter().map(|x| x.as_slice()).collect();
        let w = Whitening::fit(&refs, &seq, 5, 0.0).unwrap();
        assert_eq!(w.directions.len(), 1, "rank of Sb is 1");
        let p = &w.directions[0];
        // Within variance along x is 0.01, so |p_x| = 10; p_y = 0.
        assert!(
            (p[0].abs() - 10.0).abs() < 1e-4 && p[1].abs() < 1e-9,
            "{p:?}"
        );
        // Between variance along x is 1: ratio 1 / 0.01.
        assert!((w.ratios[0] - 100.0).abs() < 1e-3, "{}", w.ratios[0]);
        let (a, b) = (w.apply(&v[0]), w.apply(&v[4]));
        assert!((a[0] - b[0]).abs() > 15.0);
    }

    #[test]
    fn cholesky_solves() {
        let mut a = vec![4.0, 2.0, 2.0, 3.0];
        let l = cholesky(&mut a, 2).unwrap();
        assert!((l[0] - 2.0).abs() < 1e-12 && (l[2] - 1.0).abs() < 1e-12);
        assert!((l[3] - 2f64.sqrt()).abs() < 1e-12);
        let mut b = vec![2.0, 1.0 + 2f64.sqrt()];
        forward(&l, 2, &mut b);
        assert!((b[0] - 1.0).abs() < 1e-12 && (b[1] - 1.0).abs() < 1e-12);
        let mut c = vec![3.0, 2f64.sqrt()];
        backward_transposed(&l, 2, &mut c);
        assert!((c[0] - 1.0).abs() < 1e-12 && (c[1] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn one_sequence_cannot_be_whitened() {
        let v = [[1.0f32, 2.0], [2.0, 3.0]];
        let refs: Vec<&[f32]> = v.iter().map(|x| x.as_slice()).collect();
        assert!(Whitening::fit(&refs, &[0, 0], 4, 0.1).is_none());
    }
}
