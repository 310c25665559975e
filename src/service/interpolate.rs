//! Interpolation between two motions (thesis 000 §3.5–3.6, SPEC §3) with
//! Table 3.3's report, and `eval interpolate` over pairs of a corpus.

use crate::features::interpolate::{
    dct_band_swap, interpolate, mean_jerk, median_jerk, to_f64, unwrap_axis_angle,
    InterpolateOptions,
};
use crate::features::{
    rows72, smpl24_at_60, window, window_starts, Embedding, Extractor, StftParams,
};
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::{Motion, MotionError};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use serde::Serialize;
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, Serialize)]
pub struct Similarity {
    pub o_t: f64,
    pub i_o: f64,
    pub i_t: f64,
}

impl Similarity {
    /// The thesis's criterion: the output is closer to each clip than the
    /// clips are to each other.
    pub fn between(&self) -> bool {
        self.i_o > self.o_t && self.i_t > self.o_t
    }
}

/// Jerk of FK joint positions, m/s³: `input`, `output`, `target` and
/// `band_swap` (the input with its band replaced by the target's — the
/// ideal mix, and the DCT objective's exact optimum) are means over frames
/// and joints; `median` holds the same four as medians over frames, which a
/// few single-frame capture glitches do not move.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Jitter {
    pub input: f64,
    pub output: f64,
    pub target: f64,
    pub band_swap: f64,
    pub median: JerkMedians,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct JerkMedians {
    pub input: f64,
    pub output: f64,
    pub target: f64,
    pub band_swap: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct InterpolateReport {
    pub similarity: Similarity,
    pub jitter: Jitter,
    pub loss: Vec<f64>,
    pub steps: usize,
    pub seconds: f64,
    pub frames: usize,
    pub objective: Embedding,
    pub band: (usize, usize),
    /// Joint rotations replaced by the glitch repair (0 when it is off).
    pub repaired: Repaired,
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Repaired {
    pub input: usize,
    pub target: usize,
}

/// The glitch repair applied before interpolating: runs of up to 3 frames
/// (at 60 fps) that jump more than 45° and come back.
pub const DESPIKE_RUN: usize = 3;
pub const DESPIKE_DEG: f64 = 45.0;

/// A channel matrix back onto an SMPL-24 motion (its translation kept).
pub fn with_channels(m: &Motion, ch: &[[f64; 72]]) -> Motion {
    let n = ch.len().min(m.frames());
    let rots = ch[..n]
        .iter()
        .flat_map(|r| (0..24).map(move |j| [r[3 * j], r[3 * j + 1], r[3 * j + 2]]))
        .collect();
    m.with_data(m.trans[..n].to_vec(), rots)
}

/// Cosine similarity of two motions' STFT embeddings (every window at hop
/// 32, concatenated) — Table 3.3's measure.
pub fn stft_cosine(ex: &Extractor, a: &Motion, b: &Motion) -> f64 {
    let all = |m: &Motion| -> Vec<f32> {
        let ch = rows72(m);
        window_starts(ch.len(), 32)
            .into_iter()
            .flat_map(|s| ex.stft(&window(&ch, s)))
            .collect()
    };
    let (x, y) = (all(a), all(b));
    let n = x.len().min(y.len());
    let d = crate::index::dot(&x[..n], &y[..n]) as f64;
    let nx = (crate::index::dot(&x[..n], &x[..n]) as f64).sqrt();
    let ny = (crate::index::dot(&y[..n], &y[..n]) as f64).sqrt();
    d / (nx * ny).max(1e-30)
}

/// Move `input` toward `target` (both any supported skeleton; they are
/// brought to SMPL-24 at 60 fps and cut to the shorter). Returns the output
/// motion and the report.
///
/// With `despike`, single-frame capture glitches of both clips are repaired
/// first ([`Motion::despike`]): an axis-angle signal that jumps and comes
/// back is broadband, and replacing its low band leaves the rest of the
/// jump ringing through the output.
pub fn interpolate_motions(
    input: &Motion,
    target: &Motion,
    opts: &InterpolateOptions,
    despike: bool,
) -> Result<(Motion, InterpolateReport), MotionError> {
    let mut a = smpl24_at_60(input)?;
    let mut b = smpl24_at_60(target)?;
    let mut repaired = Repaired::default();
    if despike {
        (a, repaired.input) = a.despike(DESPIKE_RUN, DESPIKE_DEG.to_radians());
        (b, repaired.target) = b.despike(DESPIKE_RUN, DESPIKE_DEG.to_radians());
    }
    let t = std::time::Instant::now();
    let r = interpolate(&to_f64(&rows72(&a)), &to_f64(&rows72(&b)), opts)
        .map_err(|e| e.in_file(&format!("{} → {}", input.name, target.name)))?;
    let seconds = t.elapsed().as_secs_f64();
    let n = r.frames;
    let o = with_channels(&a, &r.output);
    let i = a.cut(0, n)?;
    let tg = b.cut(0, n)?;
    let ex = Extractor::new(StftParams::default())?;
    let (mut ua, mut ub) = (to_f64(&rows72(&i)), to_f64(&rows72(&tg)));
    unwrap_axis_angle(&mut ua);
    unwrap_axis_angle(&mut ub);
    let swap = with_channels(&i, &dct_band_swap(&ua, &ub, opts.band));
    let jitter = |m: &Motion| mean_jerk(&m.positions(), m.joints(), m.fps);
    let median = |m: &Motion| median_jerk(&m.positions(), m.joints(), m.fps);
    let report = InterpolateReport {
        similarity: Similarity {
            o_t: stft_cosine(&ex, &i, &tg),
            i_o: stft_cosine(&ex, &o, &i),
            i_t: stft_cosine(&ex, &o, &tg),
        },
        jitter: Jitter {
            input: jitter(&i),
            output: jitter(&o),
            target: jitter(&tg),
            band_swap: jitter(&swap),
            median: JerkMedians {
                input: median(&i),
                output: median(&o),
                target: median(&tg),
                band_swap: median(&swap),
            },
        },
        loss: r.loss,
        steps: r.steps,
        seconds,
        frames: n,
        objective: opts.objective,
        band: opts.band,
        repaired,
    };
    Ok((o, report))
}

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
