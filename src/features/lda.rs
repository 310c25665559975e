//! Linear discriminant analysis on token-window statistics: the
//! classification baseline of thesis Table 4.8, and the conditioning judge
//! of `choreo eval generate` (fitted on real training windows only).

/// Window features for LDA: per value slot, the mean, standard deviation
/// and mean absolute frame-to-frame change of the bin index (scaled to
/// [0, 1]).
pub fn window_features(frames: &[u32], fl: usize, bins: usize) -> Vec<f64> {
    let nv = fl - 1;
    let n = frames.len() / fl;
    let val = |f: usize, s: usize| frames[f * fl + s].min(bins as u32 - 1) as f64 / bins as f64;
    let mut out = Vec::with_capacity(3 * nv);
    for s in 0..nv {
        let mean = (0..n).map(|f| val(f, s)).sum::<f64>() / n as f64;
        let var = (0..n).map(|f| (val(f, s) - mean).powi(2)).sum::<f64>() / n as f64;
        let dif = (1..n)
            .map(|f| (val(f, s) - val(f - 1, s)).abs())
            .sum::<f64>()
            / (n.max(2) - 1) as f64;
        out.extend([mean, var.sqrt(), dif]);
    }
    out
}

/// Linear discriminant analysis with a shrunk pooled covariance
/// ((1 − γ)Σ + γ·tr(Σ)/p·I).
pub struct Lda {
    pub weights: Vec<Vec<f64>>,
    pub offsets: Vec<f64>,
}

fn cholesky_solve(a: &[f64], p: usize, b: &[f64]) -> Option<Vec<f64>> {
    let mut l = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..=i {
            let mut s = a[i * p + j];
            for k in 0..j {
                s -= l[i * p + k] * l[j * p + k];
            }
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i * p + i] = s.sqrt();
            } else {
                l[i * p + j] = s / l[j * p + j];
            }
        }
    }
    let mut y = b.to_vec();
    for i in 0..p {
        for k in 0..i {
            y[i] -= l[i * p + k] * y[k];
        }
        y[i] /= l[i * p + i];
    }
    for i in (0..p).rev() {
        for k in i + 1..p {
            y[i] -= l[k * p + i] * y[k];
        }
        y[i] /= l[i * p + i];
    }
    Some(y)
}

impl Lda {
    pub fn fit(x: &[Vec<f64>], y: &[usize], classes: usize, shrink: f64) -> Option<Lda> {
        let p = x.first()?.len();
        let mut mu = vec![vec![0.0; p]; classes];
        let mut cnt = vec![0usize; classes];
        for (xi, &c) in x.iter().zip(y) {
            cnt[c] += 1;
            for (m, v) in mu[c].iter_mut().zip(xi) {
                *m += v;
            }
        }
        for c in 0..classes {
            if cnt[c] > 0 {
                mu[c].iter_mut().for_each(|m| *m /= cnt[c] as f64);
            }
        }
        let mut cov = vec![0.0; p * p];
        for (xi, &c) in x.iter().zip(y) {
            let d: Vec<f64> = xi.iter().zip(&mu[c]).map(|(a, b)| a - b).collect();
            for i in 0..p {
                for j in 0..p {
                    cov[i * p + j] += d[i] * d[j];
                }
            }
        }
        let n = x.len().max(2) as f64;
        cov.iter_mut().for_each(|v| *v /= n - 1.0);
        let tr = (0..p).map(|i| cov[i * p + i]).sum::<f64>() / p as f64;
        for i in 0..p {
            for j in 0..p {
                cov[i * p + j] *= 1.0 - shrink;
            }
            cov[i * p + i] += shrink * tr.max(1e-12);
        }
        let total: usize = cnt.iter().sum();
        let mut weights = Vec::with_capacity(classes);
        let mut offsets = Vec::with_capacity(classes);
        for c in 0..classes {
            let w = cholesky_solve(&cov, p, &mu[c])?;
            let prior = if cnt[c] == 0 {
                f64::NEG_INFINITY
            } else {
                (cnt[c] as f64 / total as f64).ln()
            };
            offsets.push(-0.5 * w.iter().zip(&mu[c]).map(|(a, b)| a * b).sum::<f64>() + prior);
            weights.push(w);
        }
        Some(Lda { weights, offsets })
    }

    pub fn predict(&self, x: &[f64]) -> usize {
        self.weights
            .iter()
            .zip(&self.offsets)
            .map(|(w, o)| w.iter().zip(x).map(|(a, b)| a * b).sum::<f64>() + o)
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |b, (i, s)| if s > b.1 { (i, s) } else { b },
            )
            .0
    }
}
