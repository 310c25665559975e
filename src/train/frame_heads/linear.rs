//! Linear discriminants for the class heads: shrunk LDA on standardised
//! features folded onto the raw ones (centre kept apart for the graph's
//! f32 arithmetic), grouped cross-validation, and the temperature that
//! turns scores into probabilities.

use crate::features::lda::Lda;

/// `scores = W (x − centre) + b` (an empty centre is zero). The graph
/// subtracts the centre before its product too: folded into the bias, the
/// large terms of a barely varying feature would cancel in f32.
#[derive(Clone, Debug)]
pub struct Linear {
    pub weights: Vec<Vec<f64>>,
    pub bias: Vec<f64>,
    pub centre: Vec<f64>,
}

impl Linear {
    /// The same head over `n` more features in front, which it ignores
    /// (zero weights, zero centre).
    pub fn padded_front(self, n: usize) -> Linear {
        let pad = |v: Vec<f64>| [vec![0.0; n], v].concat();
        Linear {
            weights: self.weights.into_iter().map(pad).collect(),
            bias: self.bias,
            centre: pad(self.centre),
        }
    }

    pub fn scores(&self, x: &[f64]) -> Vec<f64> {
        let c = |i: usize| self.centre.get(i).copied().unwrap_or(0.0);
        self.weights
            .iter()
            .zip(&self.bias)
            .map(|(w, b)| {
                w.iter()
                    .zip(x)
                    .enumerate()
                    .map(|(i, (a, v))| a * (v - c(i)))
                    .sum::<f64>()
                    + b
            })
            .collect()
    }

    pub fn predict(&self, x: &[f64]) -> usize {
        self.scores(x)
            .into_iter()
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |b, (i, s)| if s > b.1 { (i, s) } else { b },
            )
            .0
    }
}

/// Shrunk LDA on standardised features, folded back onto the raw ones
/// (so the result applies to unscaled features, as a graph head must).
pub fn fit_lda(x: &[Vec<f64>], y: &[usize], classes: usize, shrink: f64) -> Option<Linear> {
    let p = x.first()?.len();
    let n = x.len() as f64;
    let mut mu = vec![0.0; p];
    for xi in x {
        mu.iter_mut().zip(xi).for_each(|(m, v)| *m += v / n);
    }
    let mut sd = vec![0.0; p];
    for xi in x {
        sd.iter_mut()
            .zip(xi.iter().zip(&mu))
            .for_each(|(s, (v, m))| *s += (v - m).powi(2) / n);
    }
    let sd: Vec<f64> = sd.iter().map(|v| v.sqrt()).collect();
    // A feature that does not vary in training (a slot the data never
    // moves) carries nothing, and its weight would be 1/sd: left out.
    let z: Vec<Vec<f64>> = x
        .iter()
        .map(|xi| {
            xi.iter()
                .zip(mu.iter().zip(&sd))
                .map(|(v, (m, &s))| if s > MIN_SD { (v - m) / s } else { 0.0 })
                .collect()
        })
        .collect();
    let lda = Lda::fit(&z, y, classes, shrink)?;
    let mut weights = Vec::with_capacity(classes);
    let mut bias = Vec::with_capacity(classes);
    for (w, o) in lda.weights.iter().zip(&lda.offsets) {
        let raw: Vec<f64> = w
            .iter()
            .zip(&sd)
            .map(|(a, &s)| if s > MIN_SD { a / s } else { 0.0 })
            .collect();
        // An unseen class has offset −∞; keep it finite for the graph and
        // far below any seen class.
        bias.push(if o.is_finite() { *o } else { -1e4 });
        weights.push(raw);
    }
    Some(Linear {
        weights,
        bias,
        centre: mu,
    })
}

/// Features with a smaller training standard deviation are left out.
pub const MIN_SD: f64 = 1e-6;

/// Shrinkage candidates for the cross-validated choice.
pub const SHRINKS: [f64; 7] = [0.001, 0.01, 0.03, 0.1, 0.3, 0.6, 0.9];

/// Grouped k-fold accuracy of `fit` (folds by group number).
pub fn grouped_cv(
    x: &[Vec<f64>],
    y: &[usize],
    groups: &[usize],
    folds: usize,
    fit: impl Fn(&[Vec<f64>], &[usize]) -> Option<Linear>,
) -> f64 {
    grouped_cv_scores(x, y, groups, folds, fit).0
}

/// [`grouped_cv`], with each row's out-of-fold scores (`None` where its
/// fold's fit failed or its fold's training side lacks its class).
pub fn grouped_cv_scores(
    x: &[Vec<f64>],
    y: &[usize],
    groups: &[usize],
    folds: usize,
    fit: impl Fn(&[Vec<f64>], &[usize]) -> Option<Linear>,
) -> (f64, Vec<Option<Vec<f64>>>) {
    let fold = |g: usize| (g.wrapping_mul(2_654_435_761) >> 7) % folds;
    let (mut hit, mut n) = (0usize, 0usize);
    let mut out = vec![None; x.len()];
    for f in 0..folds {
        let (mut tx, mut ty) = (Vec::new(), Vec::new());
        for ((xi, &yi), &g) in x.iter().zip(y).zip(groups) {
            if fold(g) != f {
                tx.push(xi.clone());
                ty.push(yi);
            }
        }
        let Some(m) = fit(&tx, &ty) else { continue };
        for (i, ((xi, &yi), &g)) in x.iter().zip(y).zip(groups).enumerate() {
            if fold(g) == f {
                n += 1;
                hit += (m.predict(xi) == yi) as usize;
                // A class the fold never saw cannot be scored fairly
                // (its offset is a large negative constant): left out of
                // the scores, still a miss in the accuracy.
                if ty.contains(&yi) {
                    out[i] = Some(m.scores(xi));
                }
            }
        }
    }
    (hit as f64 / n.max(1) as f64, out)
}

/// Mean negative log-likelihood (nats) of `y` under softmax(`scores / t`).
pub fn log_loss(scores: &[Option<Vec<f64>>], y: &[usize], t: f64) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (s, &c) in scores.iter().zip(y) {
        let Some(s) = s else { continue };
        let m = s.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b / t));
        let lse = m + s.iter().map(|&v| (v / t - m).exp()).sum::<f64>().ln();
        sum += lse - s[c] / t;
        n += 1;
    }
    sum / n.max(1) as f64
}

/// The temperature (on a log grid from 0.25 to 4,096) whose softmax of
/// the out-of-fold scores has the least log-loss: a discriminant's raw
/// scores on hundreds of features are far too sure of themselves, and the
/// served probabilities should mean what they say. Returns (temperature,
/// log-loss at it, log-loss at 1).
pub fn calibrate(scores: &[Option<Vec<f64>>], y: &[usize]) -> (f64, f64, f64) {
    let at1 = log_loss(scores, y, 1.0);
    (0..=56)
        .map(|i| 0.25 * 2f64.powf(i as f64 / 4.0))
        .map(|t| (t, log_loss(scores, y, t)))
        .fold(
            (1.0, at1, at1),
            |b, (t, l)| if l < b.1 { (t, l, at1) } else { b },
        )
}

impl Linear {
    /// Divides every score by `t` (the argmax is unchanged).
    pub fn tempered(mut self, t: f64) -> Linear {
        for w in self.weights.iter_mut() {
            w.iter_mut().for_each(|v| *v /= t);
        }
        self.bias.iter_mut().for_each(|v| *v /= t);
        self
    }
}

impl From<Lda> for Linear {
    fn from(l: Lda) -> Linear {
        Linear {
            weights: l.weights,
            bias: l
                .offsets
                .into_iter()
                .map(|o| if o.is_finite() { o } else { -1e4 })
                .collect(),
            centre: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The discriminant folded back onto raw features scores exactly as the
    /// one on standardised features, and separates blobs whose scales
    /// differ by orders of magnitude.
    #[test]
    fn folded_lda_matches_the_standardised_one() {
        let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(3);
        use rand::Rng;
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for i in 0..300 {
            let c = i % 3;
            let centre = [c as f64 * 1e3, -(c as f64) * 1e-3, 5.0];
            let scale = [300.0, 3e-4, 1.0];
            x.push(
                (0..3)
                    .map(|j| centre[j] + scale[j] * (rng.gen::<f64>() - 0.5))
                    .collect::<Vec<f64>>(),
            );
            y.push(c);
        }
        let raw = fit_lda(&x, &y, 3, 0.1).unwrap();
        let hits = x
            .iter()
            .zip(&y)
            .filter(|(xi, &c)| raw.predict(xi) == c)
            .count();
        assert!(hits >= 290, "{hits} of 300");
        // The same scores as the discriminant fitted on z-scores.
        let n = x.len() as f64;
        let mu: Vec<f64> = (0..3)
            .map(|j| x.iter().map(|r| r[j]).sum::<f64>() / n)
            .collect();
        let sd: Vec<f64> = (0..3)
            .map(|j| (x.iter().map(|r| (r[j] - mu[j]).powi(2)).sum::<f64>() / n).sqrt())
            .collect();
        let z: Vec<Vec<f64>> = x
            .iter()
            .map(|r| (0..3).map(|j| (r[j] - mu[j]) / sd[j]).collect())
            .collect();
        let std = Lda::fit(&z, &y, 3, 0.1).unwrap();
        for (xi, zi) in x.iter().zip(&z) {
            let scores = raw.scores(xi);
            for c in 0..3 {
                let a = scores[c];
                let b = std.weights[c]
                    .iter()
                    .zip(zi)
                    .map(|(w, v)| w * v)
                    .sum::<f64>()
                    + std.offsets[c];
                assert!((a - b).abs() < 1e-6 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
    }

    /// Cross-validation keeps a group's rows in one fold: a "classifier"
    /// that memorises groups scores nothing on unseen ones.
    #[test]
    fn grouped_folds_hold_out_whole_groups() {
        // Each group has its own class, and the feature is the group id:
        // a fit can only recall groups it saw.
        let groups: Vec<usize> = (0..40).map(|i| i / 4).collect();
        let y: Vec<usize> = groups.clone();
        let x: Vec<Vec<f64>> = groups.iter().map(|&g| vec![g as f64]).collect();
        let acc = grouped_cv(&x, &y, &groups, 5, |_, ty| {
            // Predicts only classes it was trained on.
            let mut bias = vec![f64::NEG_INFINITY; 10];
            ty.iter().for_each(|&c| bias[c] = 0.0);
            Some(Linear {
                weights: vec![vec![0.0]; 10],
                bias,
                centre: Vec::new(),
            })
        });
        assert!(acc < 0.01, "{acc}");
    }
}

#[cfg(test)]
mod calibration_tests {
    use super::*;

    /// Scores a hundred times too sure, right four times in five: the
    /// chosen temperature brings the log-loss down near the best possible.
    #[test]
    fn temperature_undoes_overconfidence() {
        let y: Vec<usize> = (0..200).map(|i| i % 2).collect();
        let scores: Vec<Option<Vec<f64>>> = y
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let right = i % 5 != 0;
                let top = if right { c } else { 1 - c };
                let mut s = vec![0.0; 2];
                s[top] = 100.0 * 1.386; // ln 4 = log-odds of 80 %, ×100
                Some(s)
            })
            .collect();
        let (t, loss, loss1) = calibrate(&scores, &y);
        assert!(loss1 > 20.0, "{loss1}");
        // Best possible: the entropy of 80/20, 0.500 nats, at t = 100.
        assert!((loss - 0.5004).abs() < 0.01, "{loss} at {t}");
        assert!((60.0..170.0).contains(&t), "{t}");
    }
}
