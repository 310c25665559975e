//! One row of `choreo eval generate` (see [`super`]): what it measures,
//! field by field, as the JSON gives it.

use serde::Serialize;
use std::collections::BTreeMap;

/// One row: a label kind under one sampling setting.
#[derive(Clone, Debug, Serialize)]
pub struct GenRow {
    pub label_kind: String,
    pub sampling: String,
    /// Samples each clip was chosen from (best of N; 1 = plain sampling).
    pub candidates: u32,
    /// With more than one candidate: continuations of this many frames
    /// were ranked as each clip was made (steering); 0 = whole clips.
    pub rank_every: usize,
    pub labels: usize,
    pub clips: usize,
    pub fid_k: Option<f64>,
    pub fid_g: Option<f64>,
    pub fid_k_real: Option<f64>,
    pub fid_g_real: Option<f64>,
    /// The real-vs-real yardstick at this row's clip count: held-out real
    /// against as many real training segments as clips were generated
    /// (median of 50 draws). FID is biased upward on small sets, so this
    /// is the figure a generator as good as the real data would get here.
    /// `None` where there are fewer training segments than clips.
    pub fid_k_real_same_n: Option<f64>,
    pub fid_g_real_same_n: Option<f64>,
    /// The real yardstick at the generated length: real training takes of
    /// each value played on to it (see [`RealChained`]); `None` with
    /// held-out lengths, or where no training take chains.
    pub real_chained: Option<RealChained>,
    /// The kinetic features the generated clips get most wrong against the
    /// held-out real ones (mean shift and spread ratio in real standard
    /// deviations; ranked by z² + (spread − 1)²): what drives FID_k.
    pub fid_k_gaps: Vec<FeatureGap>,
    /// FID_k along the real clips' first principal axis, and without it
    /// (see [`KineticAxis`]): how much of FID_k is the clips' overall
    /// activity. `None` where FID_k is.
    pub fid_k_axis: Option<KineticAxis>,
    /// 5th and 95th percentiles of FID_k / FID_g over bootstrap resamples
    /// of the generated clips (the real side fixed): how far the figure
    /// moves with which clips happened to be drawn.
    pub fid_k_range: Option<[f64; 2]>,
    pub fid_g_range: Option<[f64; 2]>,
    pub accel_ratio: f64,
    pub jerk_ratio: f64,
    pub skate_ratio: f64,
    pub frozen: f64,
    /// The held-out real clips' own share of still windows (the same test).
    pub frozen_real: f64,
    pub diversity: f64,
    pub diversity_real: f64,
    pub cond_acc: f64,
    /// The conditioning accuracy on each clip's first, second, … 2 s
    /// window: whether the label holds as the clip goes on.
    pub cond_acc_windows: Vec<f64>,
    pub cond_acc_real: f64,
    /// The conditioning accuracy per asked-for label value, generated and
    /// held-out real (`None` where the real clips of a value have no
    /// judge window): which values the model can make, and which it cannot.
    pub cond_acc_by_label: BTreeMap<String, LabelAcc>,
    /// Frames whose root tilts further from the vertical than 99 % of the
    /// real training frames do (lying, bowing past the corpus), generated
    /// and held-out real.
    pub tilt_out: f64,
    pub tilt_out_real: f64,
    /// Frames whose lowest joint is off the floor's band: more than
    /// [`super::FLOOR_SLACK`] below the real training frames' 0.5th percentile or
    /// above their 99.5th (sunk into the floor, floating), generated and
    /// held-out real.
    pub floor_out: f64,
    pub floor_out_real: f64,
    /// The bands: the tilt's 99th percentile (degrees) and the lowest
    /// joint's 0.5th–99.5th (metres, widened by FLOOR_SLACK) over the real
    /// training frames.
    pub tilt_max: f64,
    pub floor_band: [f64; 2],
    pub seconds_per_clip: f64,
    /// The generated clips' mean length (seconds of motion).
    pub seconds_generated: f64,
    /// The real clips have no root trajectory, so both sides were measured
    /// with the root held in place.
    pub root_in_place: bool,
}

/// Real training takes played on to the generated clips' length, as many
/// clips as were generated (per value, each starting from another take
/// and going on with the takes sharing its every label but the take
/// number, looping when they run out; joined where each best goes on,
/// `Motion::chain`), measured against the held-out real takes as the
/// generated clips are. Where the real takes are shorter than the
/// generated clips (Bandai: 4 s on average against 10 s), this is what
/// real motion of the label scores at the generated length.
#[derive(Clone, Debug, Serialize)]
pub struct RealChained {
    pub clips: usize,
    pub fid_k: Option<f64>,
    pub fid_g: Option<f64>,
    pub accel_ratio: f64,
    pub jerk_ratio: f64,
    pub skate_ratio: f64,
    pub diversity: f64,
}

/// One label value's conditioning accuracy ([`GenRow::cond_acc_by_label`]).
#[derive(Clone, Debug, Serialize)]
pub struct LabelAcc {
    pub generated: f64,
    pub real: Option<f64>,
}

/// The held-out real clips' first principal axis of the standardised
/// kinetic features ([`crate::keyframes::metrics::Axis`]): on motion it
/// is a clip's overall activity (every joint's speed at once: runs and
/// dashes at one end, standing and waving at the other).
#[derive(Clone, Debug, Serialize)]
pub struct KineticAxis {
    /// The axis's share of the real clips' standardised variance.
    pub real_share: f64,
    /// Variance along the axis, held-out real and generated.
    pub real_var: f64,
    pub gen_var: f64,
    /// Generated mean − real mean along the axis, in real standard
    /// deviations.
    pub shift: f64,
    /// FID_k's term along the axis alone.
    pub cost: f64,
    /// FID_k with the axis removed from both sides, beside the real
    /// yardstick at this row's clip count with it removed too.
    pub fid_k_without: f64,
    pub fid_k_real_same_n_without: Option<f64>,
    /// The three features that load the axis most (largest first).
    pub top_features: Vec<String>,
}

/// One kinetic feature's gap, generated vs held-out real.
#[derive(Clone, Debug, Serialize)]
pub struct FeatureGap {
    /// SMPL-24 joint and measure: `horizontal speed²`, `vertical speed²`
    /// or `acceleration` (the kinetic features' three per joint).
    pub feature: String,
    /// (generated mean − real mean) / real standard deviation.
    pub z: f64,
    /// Generated standard deviation / real standard deviation (see
    /// [`crate::keyframes::metrics::Gap`] for a feature real clips hold
    /// constant).
    pub spread: f64,
    /// The feature's own Fréchet term (what ranks it).
    pub cost: f64,
}

/// The kinetic feature `k`'s name ([`crate::keyframes::metrics::kinetic_features`]'s order: three
/// per SMPL-24 joint).
pub(super) fn kinetic_name(k: usize) -> String {
    let names = crate::motion::Skeleton::smpl24().names;
    let joint = names
        .get(k / 3)
        .cloned()
        .unwrap_or_else(|| format!("joint {}", k / 3));
    let what = ["horizontal speed²", "vertical speed²", "acceleration"][k % 3];
    format!("{joint} {what}")
}

/// How many kinetic features a row names in `fid_k_gaps`.
pub(super) const GAPS_SHOWN: usize = 5;
