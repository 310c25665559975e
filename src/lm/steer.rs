//! Steering by the class heads as the motion is made: every `every`
//! frames, `candidates` continuations are drawn from the same point, and
//! the one whose frames so far the model's class heads find likeliest to
//! carry the asked-for labels is kept; the next round starts from it.
//!
//! Best of N ([`super::best_of`]) ranks whole clips, so its selection
//! pressure is one choice per clip and it cannot stream. Ranking short
//! continuations makes a choice every `every` frames, frames leave in
//! chunks, and the heads read for free: each global step already gives
//! the frame's class logits (the runtime's `classify` averages those). Every
//! kept frame is still an ordinary sample of the sampling setting; only
//! which samples survive changes. It costs `candidates` times the
//! generation's work. A continuation much rougher than the round's
//! median ([`ROUGH_LIMIT`]) is not ranked: the heads can prefer a sample
//! that has started to jitter.

use super::best_of::{candidate_seed, MAX_CANDIDATES};
use super::frame::FrameConfig;
use super::frame_generator::FrameGenerator;
use super::LmError;
use crate::motion::Labels;
use std::collections::VecDeque;

/// Longest continuation ranked at once, in frames.
pub const MAX_EVERY: usize = 200;

/// A continuation whose roughness (see [`roughness`]) passes this many
/// times the round's median is not ranked: now and then a sample starts
/// to jitter, and the class heads can like what a jitter does to the pose
/// statistics.
pub const ROUGH_LIMIT: f64 = 2.0;

/// A generation steered by the class heads (frame model only).
pub struct Steered {
    gen: FrameGenerator,
    /// (kind index, value index) of each asked-for label the heads read.
    want: Vec<(usize, usize)>,
    candidates: usize,
    every: usize,
    seed: u64,
    round: u64,
    /// Frames of the kept continuation not yet handed out.
    ready: VecDeque<Vec<u32>>,
    /// The kept continuation's rank score after the latest round: Σ over
    /// the asked-for labels of the log-probability the heads give the
    /// frames so far.
    pub log_prob: f64,
    kept: usize,
}

/// The asked-for labels as (kind, value) indices of the config's class
/// heads; an error when none has a head, or a count or span out of range.
pub fn wanted(
    c: &FrameConfig,
    labels: &Labels,
    candidates: u32,
    every: usize,
) -> Result<Vec<(usize, usize)>, LmError> {
    if candidates < 2 || candidates > MAX_CANDIDATES {
        return Err(LmError::invalid(
            "request",
            "candidates",
            format!("{candidates} (steering ranks 2 to {MAX_CANDIDATES})"),
        ));
    }
    if every == 0 || every > MAX_EVERY {
        return Err(LmError::invalid(
            "request",
            "rank_every",
            format!("{every} (want 1 to {MAX_EVERY} frames; 0 ranks whole clips)"),
        ));
    }
    let want: Vec<(usize, usize)> = c
        .classes
        .iter()
        .enumerate()
        .filter_map(|(k, (kind, values))| {
            let v = labels.get(kind)?;
            values.iter().position(|x| x == v).map(|i| (k, i))
        })
        .collect();
    if want.is_empty() {
        return Err(LmError::invalid(
            "request",
            "rank_every",
            format!(
                "steering ranks by the model's class heads, and none of the asked-for labels has one (the model classifies: {})",
                c.classes.iter().map(|(k, _)| k.as_str()).collect::<Vec<_>>().join(", ")
            ),
        ));
    }
    Ok(want)
}

/// Σ over `want` of log softmax(mean logits)[value], from per-kind logit
/// sums over `frames` frames.
pub fn score(sums: &[Vec<f64>], frames: usize, want: &[(usize, usize)]) -> f64 {
    let n = frames.max(1) as f64;
    want.iter()
        .map(|&(k, i)| {
            let l: Vec<f64> = sums[k].iter().map(|x| x / n).collect();
            let m = l.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let z: f64 = l.iter().map(|x| (x - m).exp()).sum();
            l[i] - m - z.ln()
        })
        .sum()
}

/// Mean absolute second difference of the slots' bins over a
/// continuation's frames (value tokens first, `cfg.slots` of them; 0 under
/// three frames): its acceleration in bins per frame². An angle's change
/// is taken the shorter way round; the root's velocity and height slots
/// do not wrap ([`FrameConfig::wraps`]).
pub fn roughness(frames: &[Vec<u32>], cfg: &FrameConfig) -> f64 {
    let bins = cfg.bins as i64;
    let d = |a: u32, b: u32, wraps: bool| -> i64 {
        let x = a as i64 - b as i64;
        if !wraps {
            return x;
        }
        let x = x.rem_euclid(bins);
        if 2 * x > bins {
            x - bins
        } else {
            x
        }
    };
    let (mut sum, mut n) = (0.0, 0usize);
    for w in frames.windows(3) {
        for s in 0..cfg.slots {
            let wraps = cfg.wraps(s);
            sum += (d(w[2][s], w[1][s], wraps) - d(w[1][s], w[0][s], wraps)).abs() as f64;
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

/// The candidate to keep: the best score among those whose roughness is
/// at most [`ROUGH_LIMIT`] times the median's (the first on ties).
pub fn keep(scores: &[f64], rough: &[f64]) -> usize {
    let mut sorted = rough.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[(sorted.len() - 1) / 2];
    let mut best: Option<usize> = None;
    for (i, (&s, &r)) in scores.iter().zip(rough).enumerate() {
        if r <= ROUGH_LIMIT * median && best.is_none_or(|b| s > scores[b]) {
            best = Some(i);
        }
    }
    best.unwrap_or(0)
}

impl Steered {
    /// Steers `gen` (fresh: nothing produced yet) toward `labels`.
    pub fn new(
        gen: FrameGenerator,
        labels: &Labels,
        candidates: u32,
        every: usize,
        seed: u64,
    ) -> Result<Steered, LmError> {
        let want = wanted(gen.config(), labels, candidates, every)?;
        Ok(Steered {
            gen,
            want,
            candidates: candidates as usize,
            every,
            seed,
            round: 0,
            ready: VecDeque::new(),
            log_prob: 0.0,
            kept: 0,
        })
    }

    pub fn candidates(&self) -> usize {
        self.candidates
    }

    /// Frames per round.
    pub fn every(&self) -> usize {
        self.every
    }

    /// The candidate kept in the latest round.
    pub fn kept(&self) -> usize {
        self.kept
    }

    /// The next frame's tokens (separator last); `forced_at(f)` gives frame
    /// `f`'s forced slots (a joint prompt), asked ahead of time for the
    /// frames of a round.
    pub fn next_frame(
        &mut self,
        forced_at: &dyn Fn(usize) -> Vec<Option<u32>>,
    ) -> Result<Vec<u32>, LmError> {
        if self.ready.is_empty() {
            self.run_round(forced_at)?;
        }
        Ok(self.ready.pop_front().expect("a round makes frames"))
    }

    fn run_round(&mut self, forced_at: &dyn Fn(usize) -> Vec<Option<u32>>) -> Result<(), LmError> {
        let base = self.gen.produced;
        let cfg = self.gen.config().clone();
        let mut made: Vec<(f64, f64, FrameGenerator, Vec<Vec<u32>>)> = Vec::new();
        for i in 0..self.candidates {
            // Seeds differ per round and per candidate, far apart.
            let seed = candidate_seed(
                self.seed.wrapping_add(self.round.wrapping_mul(0x9E37_79B9)),
                i,
            );
            let mut g = self.gen.fork(seed)?;
            let mut frames = Vec::with_capacity(self.every);
            for j in 0..self.every {
                frames.push(g.next_frame(&forced_at(base + j))?);
            }
            let s = score(g.class_logit_sums(), g.produced, &self.want);
            made.push((s, roughness(&frames, &cfg), g, frames));
        }
        let scores: Vec<f64> = made.iter().map(|m| m.0).collect();
        let rough: Vec<f64> = made.iter().map(|m| m.1).collect();
        let i = keep(&scores, &rough);
        let (s, _, g, frames) = made.swap_remove(i);
        self.log_prob = s;
        self.kept = i;
        self.gen = g;
        self.ready = frames.into();
        self.round += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn roughness_is_the_mean_second_difference_angles_the_short_way_round() {
        let c = crate::lm::frame::test_config();
        let h = c.slots - 1;
        let f = |angle: u32, height: u32| {
            let mut v = vec![5u32; c.slots];
            (v[0], v[h]) = (angle, height);
            v
        };
        // An angle 358 → 359 → 0 → 3 (+1, +1 across the wrap, +3): second
        // differences 0 and 2 over two windows of 42 slots.
        let frames = vec![f(358, 100), f(359, 100), f(0, 100), f(3, 100)];
        let r = super::roughness(&frames, &c);
        assert!((r - 2.0 / 84.0).abs() < 1e-12, "{r}");
        assert_eq!(super::roughness(&frames[..2], &c), 0.0);
        // The height from the bottom bin to the top one is 359 bins, not 1.
        let jump = vec![f(5, 0), f(5, 0), f(5, 359)];
        let r = super::roughness(&jump, &c);
        assert!((r - 359.0 / 42.0).abs() < 1e-12, "{r}");
    }

    #[test]
    fn keep_ranks_only_the_smooth_enough() {
        // The best score is a jitter (roughness 9 against a median of 1).
        assert_eq!(
            super::keep(&[0.5, -1.0, -0.2, -3.0], &[9.0, 1.0, 1.1, 0.9]),
            2
        );
        // Without an outlier the best score wins.
        assert_eq!(super::keep(&[0.5, -1.0, -0.2], &[1.2, 1.0, 1.1]), 0);
    }

    #[test]
    fn score_is_the_log_softmax_of_the_mean_logits() {
        let sums = vec![vec![2.0, 4.0, 0.0], vec![1.0, 1.0]];
        // Mean logits [1, 2, 0] over 2 frames: log softmax at index 1.
        let z = (1f64.exp() + 2f64.exp() + 1.0).ln();
        let want = 2.0 - z;
        assert!((super::score(&sums, 2, &[(0, 1)]) - want).abs() < 1e-12);
        // Kinds add; an even split gives ln 1/2.
        let both = super::score(&sums, 2, &[(0, 1), (1, 0)]);
        assert!((both - (want + 0.5f64.ln())).abs() < 1e-12);
    }
}
