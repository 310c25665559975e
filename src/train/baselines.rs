//! Baselines the model is measured against: unigram token models (the
//! floor a language model must beat) and, for classification, the majority
//! class and linear discriminant analysis on the same windows (thesis
//! Table 4.8).

use super::data::Sequence;
pub use crate::features::lda::{window_features, Lda};
use crate::motion::Labels;

/// Cross-entropy (nats per token) on the validation frame tokens of a
/// unigram model fitted to the training frame tokens, add-one smoothed:
/// one distribution for all slots, and one per slot.
pub fn unigram_losses(
    train: &[Sequence],
    val: &[Sequence],
    vocab_size: usize,
    fl: usize,
) -> (f64, f64) {
    let mut global = vec![1f64; vocab_size];
    let mut per_slot = vec![vec![1f64; vocab_size]; fl];
    for s in train {
        for (i, &t) in s.tokens.iter().enumerate() {
            global[t as usize] += 1.0;
            per_slot[i % fl][t as usize] += 1.0;
        }
    }
    let gz: f64 = global.iter().sum();
    let sz: Vec<f64> = per_slot.iter().map(|r| r.iter().sum()).collect();
    let (mut g, mut p, mut n) = (0.0, 0.0, 0usize);
    for s in val {
        for (i, &t) in s.tokens.iter().enumerate() {
            g -= (global[t as usize] / gz).ln();
            p -= (per_slot[i % fl][t as usize] / sz[i % fl]).ln();
            n += 1;
        }
    }
    (g / n.max(1) as f64, p / n.max(1) as f64)
}

/// Cross-entropy (nats per frame token) on the validation frame tokens of
/// the previous-frame delta model: each slot's token is predicted from the
/// same slot's token one frame earlier through a per-slot distribution of
/// the change in bin index (add-one smoothed over every possible change),
/// fitted on the training tokens. A sequence's first frame, and the
/// separator slot, fall back to the per-slot unigram. The yardstick a
/// language model must clearly beat to claim it models continuity.
pub fn delta_loss(
    train: &[Sequence],
    val: &[Sequence],
    vocab_size: usize,
    bins: usize,
    fl: usize,
) -> f64 {
    let span = 2 * bins - 1;
    let mut per_slot = vec![vec![1f64; vocab_size]; fl];
    let mut delta = vec![vec![1f64; span]; fl];
    let is_value = |t: u32| (t as usize) < bins;
    for s in train {
        let n = s.tokens.len() / fl;
        for f in 0..n {
            for k in 0..fl {
                let t = s.tokens[f * fl + k];
                per_slot[k][t as usize] += 1.0;
                if f > 0 {
                    let p = s.tokens[(f - 1) * fl + k];
                    if is_value(t) && is_value(p) {
                        delta[k][(t as i64 - p as i64 + bins as i64 - 1) as usize] += 1.0;
                    }
                }
            }
        }
    }
    let sz: Vec<f64> = per_slot.iter().map(|r| r.iter().sum()).collect();
    // The changes reachable from bin `p` (all of them), so each slot's
    // prediction is a proper distribution over its values.
    let reach: Vec<Vec<f64>> = delta
        .iter()
        .map(|d| {
            (0..bins)
                .map(|p| (0..bins).map(|b| d[b + bins - 1 - p]).sum())
                .collect()
        })
        .collect();
    let (mut loss, mut count) = (0f64, 0usize);
    for s in val {
        let n = s.tokens.len() / fl;
        for f in 0..n {
            for k in 0..fl {
                let t = s.tokens[f * fl + k];
                let p = (f > 0).then(|| s.tokens[(f - 1) * fl + k]);
                loss -= match p {
                    Some(p) if is_value(t) && is_value(p) => {
                        let d = delta[k][(t as i64 - p as i64 + bins as i64 - 1) as usize];
                        (d / reach[k][p as usize]).ln()
                    }
                    _ => (per_slot[k][t as usize] / sz[k]).ln(),
                };
                count += 1;
            }
        }
    }
    loss / count.max(1) as f64
}

/// Majority-class and LDA accuracy for one label kind on fixed windows.
/// Returns (majority, lda, windows scored).
pub fn classification_baselines(
    train: &[(&[u32], &Labels)],
    val: &[(&[u32], &Labels)],
    kind: &str,
    values: &[String],
    fl: usize,
    bins: usize,
) -> (f64, f64, usize) {
    let idx = |l: &Labels| l.get(kind).and_then(|v| values.iter().position(|x| x == v));
    let (mut x, mut y) = (Vec::new(), Vec::new());
    for (f, l) in train {
        if let Some(c) = idx(l) {
            x.push(window_features(f, fl, bins));
            y.push(c);
        }
    }
    let mut counts = vec![0usize; values.len()];
    y.iter().for_each(|&c| counts[c] += 1);
    let major = counts
        .iter()
        .enumerate()
        .max_by_key(|c| c.1)
        .map(|c| c.0)
        .unwrap_or(0);
    let lda = Lda::fit(&x, &y, values.len(), 0.1);
    let (mut m_hit, mut l_hit, mut n) = (0, 0, 0);
    for (f, l) in val {
        if let Some(c) = idx(l) {
            n += 1;
            m_hit += (c == major) as usize;
            if let Some(lda) = &lda {
                l_hit += (lda.predict(&window_features(f, fl, bins)) == c) as usize;
            }
        }
    }
    let n1 = n.max(1) as f64;
    (m_hit as f64 / n1, l_hit as f64 / n1, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lda_separates_two_gaussian_blobs() {
        let mut x = Vec::new();
        let mut y = Vec::new();
        for i in 0..200 {
            let c = i % 2;
            let j = (i as f64 * 0.618).fract() - 0.5;
            let k = (i as f64 * 0.377).fract() - 0.5;
            x.push(vec![c as f64 * 2.0 + j, k * 0.5]);
            y.push(c);
        }
        let lda = Lda::fit(&x, &y, 2, 0.1).unwrap();
        assert_eq!(lda.predict(&[0.1, 0.0]), 0);
        assert_eq!(lda.predict(&[1.9, 0.0]), 1);
    }
}
