//! PCA over 128-sample channel series (thesis 000 §A.1): the covariance of
//! every (window, channel) series is accumulated in f64, diagonalised by
//! cyclic Jacobi, and the 16 leading eigenvectors kept. Each component's sign
//! is fixed so its largest-magnitude entry is positive (deterministic).

use super::{CHANNELS, COEFFS, WINDOW};
use crate::motion::MotionError;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Pca {
    /// Mean series, `[128]`.
    pub mean: Vec<f32>,
    /// Components, row-major `[16][128]`.
    pub components: Vec<f32>,
    /// Variance along each component, descending.
    pub explained_variance: Vec<f64>,
    /// How many series it was fitted on.
    pub samples: usize,
    /// The components as one blocked projection, mean folded out (made on
    /// first use).
    #[serde(skip)]
    projection: std::sync::OnceLock<super::project::Projection>,
}

impl PartialEq for Pca {
    fn eq(&self, o: &Pca) -> bool {
        (
            &self.mean,
            &self.components,
            &self.explained_variance,
            self.samples,
        ) == (&o.mean, &o.components, &o.explained_variance, o.samples)
    }
}

/// Running sums for the covariance, so windows can stream in.
pub struct PcaAccumulator {
    n: usize,
    sum: Vec<f64>,
    outer: Vec<f64>,
}

impl Default for PcaAccumulator {
    fn default() -> Self {
        PcaAccumulator {
            n: 0,
            sum: vec![0.0; WINDOW],
            outer: vec![0.0; WINDOW * WINDOW],
        }
    }
}

impl PcaAccumulator {
    /// Add the 72 channel series of one window (`[72][128]`).
    pub fn add_window(&mut self, win: &[f32]) {
        for c in 0..CHANNELS {
            let x = &win[c * WINDOW..(c + 1) * WINDOW];
            self.n += 1;
            for i in 0..WINDOW {
                let xi = x[i] as f64;
                self.sum[i] += xi;
                let row = &mut self.outer[i * WINDOW..(i + 1) * WINDOW];
                for j in i..WINDOW {
                    row[j] += xi * x[j] as f64;
                }
            }
        }
    }

    pub fn finish(self) -> Result<Pca, MotionError> {
        if self.n < 2 {
            return Err(MotionError::invalid(
                "pca",
                "windows",
                "PCA needs at least one window to fit",
            ));
        }
        let n = self.n as f64;
        let mean: Vec<f64> = self.sum.iter().map(|s| s / n).collect();
        let mut cov = vec![0.0; WINDOW * WINDOW];
        for i in 0..WINDOW {
            for j in i..WINDOW {
                // Unbiased (n - 1), as numpy / sklearn.
                let v = (self.outer[i * WINDOW + j] - n * mean[i] * mean[j]) / (n - 1.0);
                cov[i * WINDOW + j] = v;
                cov[j * WINDOW + i] = v;
            }
        }
        let (vals, vecs) = jacobi_eigen(cov, WINDOW);
        let mut order: Vec<usize> = (0..WINDOW).collect();
        order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]));
        let mut components = Vec::with_capacity(COEFFS * WINDOW);
        let mut explained = Vec::with_capacity(COEFFS);
        for &k in order.iter().take(COEFFS) {
            let mut v: Vec<f64> = (0..WINDOW).map(|i| vecs[i * WINDOW + k]).collect();
            let big = v
                .iter()
                .cloned()
                .fold(0.0f64, |a, b| if b.abs() > a.abs() { b } else { a });
            if big < 0.0 {
                v.iter_mut().for_each(|x| *x = -*x);
            }
            components.extend(v.iter().map(|&x| x as f32));
            explained.push(vals[k].max(0.0));
        }
        Ok(Pca {
            mean: mean.iter().map(|&m| m as f32).collect(),
            components,
            explained_variance: explained,
            samples: self.n,
            projection: Default::default(),
        })
    }
}

impl Pca {
    pub fn fit<'a>(windows: impl IntoIterator<Item = &'a [f32]>) -> Result<Pca, MotionError> {
        let mut acc = PcaAccumulator::default();
        for w in windows {
            acc.add_window(w);
        }
        acc.finish()
    }

    /// Project each channel's series: `[72][16]`.
    pub fn project_window(&self, win: &[f32]) -> Vec<f32> {
        self.projection
            .get_or_init(|| super::project::Projection::new(&self.components, Some(&self.mean)))
            .apply(win)
    }

    pub fn validate(&self) -> Result<(), MotionError> {
        if self.mean.len() != WINDOW || self.components.len() != COEFFS * WINDOW {
            return Err(MotionError::invalid(
                "pca",
                "model",
                "stored PCA model has the wrong shape",
            ));
        }
        Ok(())
    }
}

/// `a · b` for `d × d` row-major matrices.
pub fn matmul(a: &[f64], b: &[f64], d: usize) -> Vec<f64> {
    let mut out = vec![0.0; d * d];
    for i in 0..d {
        for m in 0..d {
            let x = a[i * d + m];
            if x == 0.0 {
                continue;
            }
            for (o, y) in out[i * d..(i + 1) * d]
                .iter_mut()
                .zip(&b[m * d..(m + 1) * d])
            {
                *o += x * y;
            }
        }
    }
    out
}

/// Cyclic Jacobi eigen-decomposition of a symmetric `n × n` matrix
/// (row-major). Returns (eigenvalues, eigenvectors as columns, row-major).
pub fn jacobi_eigen(mut a: Vec<f64>, n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..100 {
        let mut off = 0.0;
        for i in 0..n {
            for j in (i + 1)..n {
                off += a[i * n + j] * a[i * n + j];
            }
        }
        let scale: f64 = (0..n).map(|i| a[i * n + i].abs()).sum::<f64>().max(1e-300);
        if off.sqrt() < 1e-15 * scale {
            break;
        }
        for p in 0..n {
            for q in (p + 1)..n {
                let apq = a[p * n + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let app = a[p * n + p];
                let aqq = a[q * n + q];
                let theta = (aqq - app) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let akp = a[k * n + p];
                    let akq = a[k * n + q];
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let apk = a[p * n + k];
                    let aqk = a[q * n + k];
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for k in 0..n {
                    let vkp = v[k * n + p];
                    let vkq = v[k * n + q];
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i * n + i]).collect(), v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_on_a_known_matrix() {
        // [[2,1],[1,2]] has eigenvalues 1 and 3.
        let (vals, vecs) = jacobi_eigen(vec![2.0, 1.0, 1.0, 2.0], 2);
        let mut s = vals.clone();
        s.sort_by(f64::total_cmp);
        assert!((s[0] - 1.0).abs() < 1e-12 && (s[1] - 3.0).abs() < 1e-12);
        // Columns are orthonormal.
        let d = vecs[0] * vecs[1] + vecs[2] * vecs[3];
        assert!(d.abs() < 1e-12);
    }

    #[test]
    fn pca_finds_the_one_varying_direction() {
        // Series = a * u + mean, with u a fixed unit shape: one component.
        let u: Vec<f32> = (0..WINDOW).map(|t| ((t as f32) * 0.1).sin()).collect();
        let norm = u.iter().map(|x| x * x).sum::<f32>().sqrt();
        let mut wins = Vec::new();
        for k in 0..20 {
            let mut w = vec![0f32; CHANNELS * WINDOW];
            for c in 0..CHANNELS {
                let a = ((k * CHANNELS + c) as f32 * 0.37).sin();
                for t in 0..WINDOW {
                    w[c * WINDOW + t] = 0.3 + a * u[t] / norm;
                }
            }
            wins.push(w);
        }
        let p = Pca::fit(wins.iter().map(|w| w.as_slice())).unwrap();
        let first = &p.components[..WINDOW];
        let dot: f32 = first.iter().zip(&u).map(|(a, b)| a * b / norm).sum();
        assert!((dot.abs() - 1.0).abs() < 1e-4, "{dot}");
        assert!(p.explained_variance[1] < 1e-6 * p.explained_variance[0]);
    }
}
