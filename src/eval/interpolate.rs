//! `eval interpolate`: Table 3.3 over pairs of a corpus's sequences.

use crate::features::interpolate::InterpolateOptions;
use crate::features::Embedding;
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::MotionError;
use crate::service::interpolate::{interpolate_motions, Jitter, Similarity};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use serde::Serialize;
use std::path::PathBuf;

#[derive(Clone, Debug, Serialize)]
pub struct PairRow {
    pub pair: usize,
    pub input: String,
    pub target: String,
    pub objective: Embedding,
    pub similarity: Similarity,
    pub between: bool,
    pub jitter: Jitter,
    pub final_loss: f64,
    pub seconds: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ObjectiveSummary {
    pub objective: Embedding,
    pub pairs: usize,
    pub mean_o_t: f64,
    pub mean_i_o: f64,
    pub mean_i_t: f64,
    /// Pairs whose output lies between the clips (I→O and I→T > O→T).
    pub between: usize,
    pub mean_jerk_input: f64,
    pub mean_jerk_output: f64,
    pub mean_jerk_band_swap: f64,
    /// Median over pairs of (median-over-frames) output jerk / band-swap
    /// jerk: how much jitter the objective adds beyond the ideal mix.
    pub median_jerk_ratio: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct EvalInterpolate {
    pub rows: Vec<PairRow>,
    pub summary: Vec<ObjectiveSummary>,
    pub files: usize,
    pub errors: Vec<String>,
}

/// `pairs` ordered pairs of distinct sequences drawn with `seed`, each
/// interpolated with every objective in `objectives` (same band, steps,
/// learning rate).
pub fn eval_interpolate(
    files: &[PathBuf],
    pairs: usize,
    seed: u64,
    objectives: &[Embedding],
    base: &InterpolateOptions,
    despike: bool,
) -> Result<EvalInterpolate, MotionError> {
    let mut motions = vec![];
    let mut errors = vec![];
    for f in files {
        match read_path(f, &ReadOptions::default()) {
            Ok(l) if l.motion.duration_s() * 60.0 >= crate::features::WINDOW as f64 => {
                motions.push(l.motion)
            }
            Ok(l) => errors.push(format!(
                "{}: shorter than a 128-frame window",
                l.motion.name
            )),
            Err(e) => errors.push(e.to_string()),
        }
    }
    if motions.len() < 2 {
        return Err(MotionError::invalid(
            "eval interpolate",
            "data",
            format!(
                "need at least 2 readable clips of 128+ frames, found {}",
                motions.len()
            ),
        ));
    }
    let mut all: Vec<(usize, usize)> = (0..motions.len())
        .flat_map(|i| {
            (0..motions.len())
                .filter(move |&j| j != i)
                .map(move |j| (i, j))
        })
        .collect();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    all.shuffle(&mut rng);
    all.truncate(pairs);
    let mut rows = vec![];
    for (p, &(i, j)) in all.iter().enumerate() {
        for &objective in objectives {
            let opts = InterpolateOptions {
                objective,
                ..base.clone()
            };
            let (_, r) = interpolate_motions(&motions[i], &motions[j], &opts, despike)?;
            rows.push(PairRow {
                pair: p,
                input: motions[i].name.clone(),
                target: motions[j].name.clone(),
                objective,
                similarity: r.similarity,
                between: r.similarity.between(),
                jitter: r.jitter,
                final_loss: *r.loss.last().unwrap_or(&f64::NAN),
                seconds: r.seconds,
            });
        }
    }
    let summary = objectives
        .iter()
        .map(|&o| {
            let rs: Vec<&PairRow> = rows.iter().filter(|r| r.objective == o).collect();
            let n = rs.len().max(1) as f64;
            let mean = |f: &dyn Fn(&PairRow) -> f64| rs.iter().map(|r| f(r)).sum::<f64>() / n;
            let mut ratios: Vec<f64> = rs
                .iter()
                .map(|r| r.jitter.median.output / r.jitter.median.band_swap.max(1e-12))
                .collect();
            ratios.sort_by(f64::total_cmp);
            ObjectiveSummary {
                objective: o,
                pairs: rs.len(),
                mean_o_t: mean(&|r| r.similarity.o_t),
                mean_i_o: mean(&|r| r.similarity.i_o),
                mean_i_t: mean(&|r| r.similarity.i_t),
                between: rs.iter().filter(|r| r.between).count(),
                mean_jerk_input: mean(&|r| r.jitter.input),
                mean_jerk_output: mean(&|r| r.jitter.output),
                mean_jerk_band_swap: mean(&|r| r.jitter.band_swap),
                median_jerk_ratio: ratios.get(ratios.len() / 2).copied().unwrap_or(f64::NAN),
            }
        })
        .collect();
    Ok(EvalInterpolate {
        rows,
        summary,
        files: files.len(),
        errors,
    })
}
