//! Which training sequences are drawn how often, for both trainers (the
//! frame model's windows and the flat GPT's): length-weighted draws,
//! each corpus's frames counted as often as its `--corpus-weight` says,
//! optionally balanced over a label kind's values (`--balance`).

use super::data::{Corpus, Sequence};
use anyhow::{bail, Result};
use std::collections::BTreeMap;

/// Cumulative frame counts for length-weighted sequence draws (every
/// corpus weighted alike).
pub fn cumulative(corpus: &Corpus, fl: usize) -> Vec<usize> {
    draw_weights(&corpus.train, fl, &Default::default(), None)
        .expect("no weights or balance to check")
}

/// Each corpus's share of the draws `cum` ([`draw_weights`]) of `train`.
pub fn shares(train: &[Sequence], cum: &[usize]) -> BTreeMap<String, f64> {
    let total = *cum.last().unwrap_or(&1) as f64;
    let mut out = BTreeMap::new();
    let mut prev = 0;
    for (s, &c) in train.iter().zip(cum) {
        *out.entry(s.corpus.clone()).or_insert(0.0) += (c - prev) as f64 / total;
        prev = c;
    }
    out
}

/// Logs each corpus's share of the draws `cum` of `train`.
pub fn log_shares(train: &[Sequence], cum: &[usize]) {
    tracing::info!(
        "draws per corpus: {}",
        shares(train, cum)
            .iter()
            .map(|(k, v)| format!("{k} {:.1} %", 100.0 * v))
            .collect::<Vec<_>>()
            .join(", ")
    );
}

/// Cumulative draw weights of the training sequences, for
/// [`super::frame_run::FrameData::balanced`] and the flat GPT's window
/// draws: each sequence's frame count times its corpus's weight (1 for a
/// corpus not named), and with `balance` = a label kind, the sequences
/// that carry it drawn so that each of its values gets the same share of
/// their draws (their total unchanged). A weight naming a corpus no
/// training sequence has, a weight that is not a positive finite number,
/// or a balanced kind no sequence carries is an error naming its flag.
pub fn draw_weights(
    train: &[Sequence],
    fl: usize,
    weights: &BTreeMap<String, f64>,
    balance: Option<&str>,
) -> Result<Vec<usize>> {
    for (name, w) in weights {
        if !train.iter().any(|s| &s.corpus == name) {
            let mut have: Vec<&str> = train.iter().map(|s| s.corpus.as_str()).collect();
            have.sort();
            have.dedup();
            bail!("--corpus-weight: no training sequence comes from corpus {name:?} (the corpora read: {have:?})");
        }
        if !(w.is_finite() && *w > 0.0) {
            bail!("--corpus-weight: the weight of {name:?} must be a positive number, not {w}");
        }
    }
    let base = |s: &Sequence| {
        (s.frames(fl).max(1) as f64) * weights.get(&s.corpus).copied().unwrap_or(1.0)
    };
    // Per value of the balanced kind: its sequences' summed weight.
    let mut by_value: BTreeMap<&str, f64> = BTreeMap::new();
    if let Some(kind) = balance {
        for s in train {
            if let Some(v) = s.labels.get(kind) {
                *by_value.entry(v.as_str()).or_insert(0.0) += base(s);
            }
        }
        if by_value.is_empty() {
            bail!("--balance: no training sequence carries a {kind:?} label");
        }
    }
    let even = by_value.values().sum::<f64>() / by_value.len().max(1) as f64;
    if let Some(kind) = balance {
        let total: f64 = train.iter().map(base).sum();
        tracing::info!(
            "balanced on {kind}: {} values, each {:.2} % of the draws (before: {})",
            by_value.len(),
            100.0 * even / total,
            by_value
                .iter()
                .map(|(v, w)| format!("{v} {:.2} %", 100.0 * w / total))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    // Balanced weights are fractions of frames: scaled so that rounding
    // does not move a short take's share (plain draws keep whole frame
    // counts, so a run resumed from before the flag draws as it did).
    let scale = if balance.is_some() { 16.0 } else { 1.0 };
    let mut acc = 0;
    Ok(train
        .iter()
        .map(|s| {
            let value = balance.and_then(|k| s.labels.get(k));
            let w = match value.and_then(|v| by_value.get(v.as_str())) {
                Some(total) => base(s) * even / total,
                None => base(s),
            };
            acc += (scale * w).round().max(1.0) as usize;
            acc
        })
        .collect())
}
