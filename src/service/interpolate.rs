//! Interpolation between two motions (thesis 000 §3.5–3.6, SPEC §3) with
//! Table 3.3's report, and the use case that runs it on the heavy pool.

use super::input::MotionInput;
use super::{auth, ApiError, Choreo};
use crate::features::interpolate::{
    dct_band_swap, interpolate as interpolate_channels, mean_jerk, median_jerk, to_f64,
    unwrap_axis_angle, InterpolateOptions,
};
use crate::features::{
    rows72, smpl24_at_60, window, window_starts, Embedding, Extractor, StftParams,
};
use crate::motion::{Motion, MotionError};
use serde::Serialize;

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
    let r = interpolate_channels(&to_f64(&rows72(&a)), &to_f64(&rows72(&b)), opts)
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

pub struct InterpolateParams {
    pub input: MotionInput,
    pub target: MotionInput,
    pub band: (usize, usize),
    pub objective: String,
    pub steps: usize,
    pub learning_rate: f64,
    pub despike: bool,
}

pub async fn interpolate(
    state: &Choreo,
    p: InterpolateParams,
    who: &auth::Principal,
) -> Result<(Motion, InterpolateReport), ApiError> {
    let a = state.resolve("input", p.input, who).await?;
    let b = state.resolve("target", p.target, who).await?;
    let objective = match p.objective.as_str() {
        "" => Embedding::Dct,
        o => Embedding::parse(o).ok_or_else(|| {
            ApiError::invalid("objective", format!("'{o}' is not dct, stft or pca"))
        })?,
    };
    let defaults = InterpolateOptions::default();
    let opts = InterpolateOptions {
        objective,
        band: if p.band == (0, 0) {
            defaults.band
        } else {
            p.band
        },
        steps: if p.steps == 0 {
            defaults.steps
        } else {
            p.steps
        },
        learning_rate: if p.learning_rate == 0.0 {
            defaults.learning_rate
        } else {
            p.learning_rate
        },
    };
    if opts.steps > 5000 {
        return Err(ApiError::invalid(
            "steps",
            format!("{}; at most 5000 per request", opts.steps),
        ));
    }
    let despike = p.despike;
    state
        .heavy("interpolate", move || {
            Ok(interpolate_motions(&a, &b, &opts, despike)?)
        })
        .await
}
