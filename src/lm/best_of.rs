//! Best of N: generate several clips for one labelled request (each with
//! its own sampling seed, [`candidate_seed`]) and keep the one the model's own class heads
//! find likeliest to carry the asked-for labels.
//!
//! The frame model barely reads its labels while it decodes (docs/RESULTS.md, "What
//! the labels are worth"), but its fitted class heads read a finished clip
//! well (Table 4.8). Ranking whole samples by them steers without touching
//! how each frame is drawn: every candidate is an ordinary sample, so the
//! motion's smoothness is that of the sampling setting; only which sample
//! is returned changes. It costs N generations, so it is for one-shot
//! requests (a stream sends frames as they are made).

use super::model::{ClassTable, MotionModel};
use super::LmError;
use crate::motion::Labels;

/// The sampling seed of candidate `i` of a request seeded `seed` (far
/// apart, so that candidates of neighbouring seeds do not repeat).
pub fn candidate_seed(seed: u64, i: usize) -> u64 {
    seed.wrapping_add(i as u64 * 1_000_003)
}

/// Most candidates one request may ask for.
pub const MAX_CANDIDATES: u32 = 16;

/// Windows of the model's context a candidate is classified on.
const RANK_WINDOWS: usize = 4;

/// The kept candidate.
#[derive(Clone, Debug)]
pub struct Choice {
    /// Its index (its sampling seed: [`candidate_seed`]).
    pub index: usize,
    pub candidates: usize,
    /// Σ over the asked-for labels of the log-probability the class heads
    /// give it.
    pub log_prob: f64,
    pub tokens: Vec<u32>,
}

/// Σ over the asked-for labels that the table has a head for of the log
/// of their probability; `None` when no label has a head.
pub fn label_log_prob(table: &ClassTable, labels: &Labels) -> Option<f64> {
    let mut sum = None;
    for (kind, probs) in table {
        let Some(want) = labels.get(kind) else {
            continue;
        };
        let p = probs.iter().find(|(v, _)| v == want).map_or(0.0, |x| x.1);
        *sum.get_or_insert(0.0) += p.max(1e-12).ln();
    }
    sum
}

/// Checks that `candidates` can be ranked for `labels` by `model`: a
/// count from 1 to [`MAX_CANDIDATES`], and above 1 a label the model has
/// a class head for.
pub fn check(model: &MotionModel, labels: &Labels, candidates: u32) -> Result<(), LmError> {
    if candidates == 0 || candidates > MAX_CANDIDATES {
        return Err(LmError::invalid(
            "request",
            "candidates",
            format!("{candidates} (want 1 to {MAX_CANDIDATES})"),
        ));
    }
    if candidates > 1 && !model.class_kinds().iter().any(|k| labels.contains_key(k)) {
        return Err(LmError::invalid(
            "request",
            "candidates",
            format!(
                "more than one candidate is ranked by the model's class heads, and none of the asked-for labels has one (the model classifies: {})",
                model.class_kinds().join(", ")
            ),
        ));
    }
    Ok(())
}

/// Makes `candidates` clips with `make(i)` and keeps the one whose class
/// probabilities give the asked-for labels the most log-probability (the
/// first on ties; the only one when `candidates` is 1).
pub fn best_of(
    model: &MotionModel,
    labels: &Labels,
    candidates: u32,
    mut make: impl FnMut(usize) -> Result<Vec<u32>, LmError>,
) -> Result<Choice, LmError> {
    check(model, labels, candidates)?;
    let n = candidates as usize;
    let mut best: Option<Choice> = None;
    for i in 0..n {
        let tokens = make(i)?;
        let log_prob = if n == 1 {
            0.0
        } else {
            let table = model.classify(&tokens, RANK_WINDOWS)?;
            label_log_prob(&table, labels).unwrap_or(f64::NEG_INFINITY)
        };
        if best.as_ref().is_none_or(|b| log_prob > b.log_prob) {
            best = Some(Choice {
                index: i,
                candidates: n,
                log_prob,
                tokens,
            });
        }
    }
    Ok(best.expect("at least one candidate"))
}

#[cfg(test)]
mod tests {
    use super::label_log_prob;
    use crate::motion::Labels;

    #[test]
    fn the_asked_for_labels_log_probabilities_add() {
        let table = vec![
            (
                "genre".to_string(),
                vec![("BR".to_string(), 0.25), ("JS".to_string(), 0.75)],
            ),
            ("dancer".to_string(), vec![("d01".to_string(), 0.5)]),
        ];
        let mut l = Labels::new();
        l.insert("genre".into(), "JS".into());
        assert!((label_log_prob(&table, &l).unwrap() - 0.75f64.ln()).abs() < 1e-12);
        l.insert("dancer".into(), "d01".into());
        let want = 0.75f64.ln() + 0.5f64.ln();
        assert!((label_log_prob(&table, &l).unwrap() - want).abs() < 1e-12);
        // A label with no head does not count; none at all gives None.
        let mut only = Labels::new();
        only.insert("situation".into(), "basic".into());
        assert!(label_log_prob(&table, &only).is_none());
    }
}
