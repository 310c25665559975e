//! How a generator draws each token: [`Sampling`] (temperature, top-k,
//! top-p, and the frame model's keep_near, max_jump, guidance and posture),
//! its checks, and [`RECOMMENDED`], what a request naming none gets.

use super::LmError;
use rand::rngs::StdRng;
use rand::Rng;

/// How tokens are drawn: greedy when `temperature` is 0 (the thesis's
/// choice), else softmax at `temperature`, keeping the `top_k` most likely
/// (0 = all) and the smallest set reaching probability `top_p` (1 = all).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Sampling {
    pub temperature: f64,
    pub top_k: usize,
    pub top_p: f64,
    pub seed: u64,
    /// Classifier-free guidance on the frame model's global state:
    /// `h_u + guidance (h_c − h_u)` between the labelled and the unlabelled
    /// state (1 = plain conditioning; needs labels and a model trained with
    /// the conditioning at every frame; costs a second global step a frame).
    pub guidance: f64,
    /// Frame model only: the changes of at most this many bins (either
    /// way) from the previous frame are never cut by `top_k` / `top_p`.
    /// Slow joints move a bin every few frames; a nucleus that cuts their
    /// ±1 changes freezes them (0 = cut like any other token).
    pub keep_near: u32,
    /// Frame model only: no slot moves more than this many bins (1° for a
    /// joint angle; the shorter way round) from one frame to the next
    /// (0 = no limit). The model can always jump (an escape to any bin
    /// outside its change window), and one jump invites the next: a clip
    /// that starts to jitter rarely recovers.
    pub max_jump: u32,
    /// Frame model only: the pull of every joint toward where the asked-for
    /// labels hold it in their training takes ([`super::posture`]; 0 = off;
    /// needs labels and the model folder's postures.json).
    pub posture: f64,
    /// Frame model only: the frames of history the global transformer
    /// reads (0 = the model's whole window, 200 for the bundled model).
    /// A shorter history leaves the labels more of the prediction: the
    /// clip holds its label longer, and moves less (docs/RESULTS.md, "A shorter
    /// history holds the label").
    pub context: u32,
    /// Frame model only: candidate frames drawn for each frame (each slot
    /// by the settings above), of which the one whose surprise under the
    /// model (nats, summed over its drawn slots) lies nearest its
    /// expectation (the slots' summed entropies, each given the slots
    /// drawn before it) is kept: a frame typical of the model, neither
    /// its likeliest (which stills the body: 49 % of 1 s windows frozen
    /// when the likeliest of 4 is kept) nor one where several slots fell
    /// in their tails at once (jitter). 1 = plain drawing; each candidate
    /// costs a pass of the local decoder (docs/RESULTS.md, "Session 37").
    pub draws: u32,
    /// Frame model only, with `draws` ≥ 2: how strongly the kept candidate
    /// holds the pace (the legs' and arms' angular speed, the root's ground
    /// speed and the joints' acceleration over the last 0.5 s) of the
    /// motion the clip continues, a seed motion or a style exemplar
    /// ([`super::pace`]; 0 = off; nothing to hold without one). Added to
    /// each candidate's distance from typical, in nats per unit of log
    /// ratio.
    pub pace: f64,
    /// Frame model only, with `draws` ≥ 2: how strongly the kept
    /// candidate avoids jerk, the change of each joint angle's
    /// acceleration over it and the three frames before
    /// ([`super::typical::frame_jerk`], in bins, the root's rotation
    /// counted three times: it swings the whole body). Added to each
    /// candidate's distance from typical, in nats per bin; 0 = off. With
    /// the whole nucleus (top-p 1) the candidates keep the fast tail of
    /// each joint's change, and this keeps the one that does not jitter
    /// (docs/RESULTS.md, "Session 40").
    pub jerk: f64,
    /// Frame model only, with a posture pull: how far the pull eases off
    /// while the clip moves slower than the motion it continues (a seed
    /// motion or a style exemplar). Each frame the pull is scaled by
    /// `min(1, r)^ease`, r the legs' and arms' joint speed over the last
    /// 0.5 s against the seed's mean ([`super::pace::Pace::turn_ratio`]);
    /// at or above the seed's pace the pull is whole. The pull damps every
    /// swing, and a clip held by it slows second by second; eased, a slow
    /// clip is left to the model, which holds its pace (docs/RESULTS.md,
    /// "Session 42"). 0 = off; nothing to ease against without a seed.
    pub ease: f64,
    /// Frame model only, with labels: how strongly each joint follows the
    /// asked-for labels' real takes (motion matching, [`super::matching`]):
    /// each frame the nearest real frame of the labels (pose and change,
    /// among the model folder's exemplar spans) is found and every joint
    /// is pulled toward where that take goes next, half-way corrected
    /// toward the clip's own pose. With it, the posture pull holds only
    /// the body's tilt. 0 = off; needs labels and the folder's
    /// exemplars.json (docs/RESULTS.md, "Session 43").
    pub matching: f64,
    /// Frame model only, with `matching`: how strongly the root's ground
    /// velocity follows the matched take's travel (in the body's own
    /// heading), as a share of the joints' pull: 1 = as strongly as the
    /// joints (the default), 0 = the root's travel left to the model
    /// while the joints still follow the takes. Tied to the takes, the
    /// feet slide less; left to the model, a model whose legs move less
    /// than real keeps the activity its root's drift gives the clip
    /// (docs/RESULTS.md, "Session 48").
    pub travel: f64,
    /// Frame model only, with `draws` ≥ 2: how strongly the kept
    /// candidate keeps planted feet still: the summed ground speed (m/s)
    /// of the ankles on the floor both in the frame before and in it
    /// ([`super::skate`]). Added to each candidate's
    /// distance from typical, in nats per m/s; 0 = off.
    pub skate: f64,
}

impl Default for Sampling {
    fn default() -> Self {
        Sampling {
            temperature: 0.0,
            top_k: 0,
            top_p: 1.0,
            seed: 0,
            guidance: 1.0,
            keep_near: 0,
            max_jump: 0,
            posture: 0.0,
            context: 0,
            draws: 1,
            pace: 0.0,
            jerk: 0.0,
            ease: 0.0,
            matching: 0.0,
            travel: 1.0,
            skate: 0.0,
        }
    }
}

/// The sampling a request gets when it names none (only a seed, or
/// nothing): of the settings `choreo eval generate` scored on held-out
/// Bandai (style) and AIST++-VRM (genre) clips with the bundled frame
/// model, the one that keeps the body moving with acceleration and jerk
/// nearest real (docs/RESULTS.md, "Generation"): t 1, top-p 0.95, and the ±1-bin
/// changes never cut (`keep_near` 1; without it, continuing a style
/// exemplar froze 27 % / 25 % of 1 s windows, with it 8 % / 13 %; since
/// session 19 the ±2-bin changes, which brought AIST++-VRM's frozen share
/// from 15 % to 9–10 % and its acceleration from 0.57 to 0.68–0.71 of
/// real), and no slot moving more than 48 bins a frame (`max_jump`: fewer
/// clips that jitter away; docs/RESULTS.md, "Exemplars the heads choose").
/// Greedy decoding freezes the body: the likeliest change of every slot
/// is "none".
pub const RECOMMENDED: Sampling = Sampling {
    temperature: 1.0,
    top_k: 0,
    top_p: 0.95,
    seed: 0,
    guidance: 1.0,
    keep_near: 2,
    max_jump: 48,
    posture: 0.0,
    context: 0,
    draws: 1,
    pace: 0.0,
    jerk: 0.0,
    ease: 0.0,
    matching: 0.0,
    travel: 1.0,
    skate: 0.0,
};

/// The most candidate frames `sampling.draws` may ask for.
pub const MAX_DRAWS: u32 = 16;

impl Sampling {
    /// [`RECOMMENDED`] with this seed.
    pub fn recommended(seed: u64) -> Sampling {
        Sampling {
            seed,
            ..RECOMMENDED
        }
    }

    pub fn validate(&self) -> Result<(), LmError> {
        if !(self.temperature.is_finite() && (0.0..=10.0).contains(&self.temperature)) {
            return Err(LmError::invalid(
                "request",
                "sampling.temperature",
                format!("{} (want 0 to 10; 0 = greedy)", self.temperature),
            ));
        }
        if !(self.guidance.is_finite() && (0.0..=10.0).contains(&self.guidance)) {
            return Err(LmError::invalid(
                "request",
                "sampling.guidance",
                format!("{} (want 0 to 10; 1 = plain conditioning)", self.guidance),
            ));
        }
        if self.keep_near > 64 {
            return Err(LmError::invalid(
                "request",
                "sampling.keep_near",
                format!("{} (want 0 to 64 bins)", self.keep_near),
            ));
        }
        if !(self.posture.is_finite() && (0.0..=10.0).contains(&self.posture)) {
            return Err(LmError::invalid(
                "request",
                "sampling.posture",
                format!("{} (want 0 to 10; 0 = off)", self.posture),
            ));
        }
        if self.context == 1 {
            return Err(LmError::invalid(
                "request",
                "sampling.context",
                "1 (want 0 = the model's whole window, or at least 2 frames)",
            ));
        }
        if !(1..=MAX_DRAWS).contains(&self.draws) {
            return Err(LmError::invalid(
                "request",
                "sampling.draws",
                format!("{} (want 1 to {MAX_DRAWS}; 1 = plain drawing)", self.draws),
            ));
        }
        // The candidates' prices: the pace hold, the jerk and skate prices.
        for (field, v) in [
            ("sampling.pace", self.pace),
            ("sampling.jerk", self.jerk),
            ("sampling.skate", self.skate),
        ] {
            if !(v.is_finite() && (0.0..=100.0).contains(&v)) {
                return Err(LmError::invalid(
                    "request",
                    field,
                    format!("{v} (want 0 to 100; 0 = off)"),
                ));
            }
            if v > 0.0 && self.draws < 2 && self.temperature > 0.0 {
                return Err(LmError::invalid(
                    "request",
                    field,
                    format!(
                        "{v} needs candidates to choose among (sampling.draws 2 or more; it is {})",
                        self.draws
                    ),
                ));
            }
        }
        if !(self.ease.is_finite() && (0.0..=10.0).contains(&self.ease)) {
            return Err(LmError::invalid(
                "request",
                "sampling.ease",
                format!("{} (want 0 to 10; 0 = off)", self.ease),
            ));
        }
        if self.ease > 0.0 && self.posture == 0.0 {
            return Err(LmError::invalid(
                "request",
                "sampling.ease",
                format!(
                    "{} eases the posture pull, and there is none (sampling.posture is 0)",
                    self.ease
                ),
            ));
        }
        if !(self.matching.is_finite() && (0.0..=10.0).contains(&self.matching)) {
            return Err(LmError::invalid(
                "request",
                "sampling.matching",
                format!("{} (want 0 to 10; 0 = off)", self.matching),
            ));
        }
        if !(self.travel.is_finite() && (0.0..=10.0).contains(&self.travel)) {
            return Err(LmError::invalid(
                "request",
                "sampling.travel",
                format!(
                    "{} (want 0 to 10; 1 = as strongly as the joints, 0 = left to the model)",
                    self.travel
                ),
            ));
        }
        if self.max_jump > 180 {
            return Err(LmError::invalid(
                "request",
                "sampling.max_jump",
                format!("{} (want 0 to 180 bins; 0 = no limit)", self.max_jump),
            ));
        }
        if !(self.top_p > 0.0 && self.top_p <= 1.0) {
            return Err(LmError::invalid(
                "request",
                "sampling.top_p",
                format!("{} (want 0 < top_p ≤ 1)", self.top_p),
            ));
        }
        Ok(())
    }

    /// Draws one index from `logits` (a slot's allowed range).
    pub fn draw(&self, logits: &[f32], rng: &mut StdRng) -> usize {
        self.draw_keeping(logits, rng, |_| false)
    }

    /// As [`Sampling::draw`], but the indices `kept` says yes to are never
    /// cut by top-k or top-p (they still need their own probability).
    pub fn draw_keeping(
        &self,
        logits: &[f32],
        rng: &mut StdRng,
        kept: impl Fn(usize) -> bool,
    ) -> usize {
        let argmax = || {
            logits
                .iter()
                .enumerate()
                .fold(
                    (0, f32::NEG_INFINITY),
                    |b, (i, &v)| if v > b.1 { (i, v) } else { b },
                )
                .0
        };
        if self.temperature == 0.0 {
            return argmax();
        }
        let t = self.temperature as f32;
        if self.top_k == 0 && self.top_p >= 1.0 {
            // Nothing is cut: draw straight from the weights, unsorted.
            let m = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let w: Vec<f64> = logits.iter().map(|&x| ((x - m) / t).exp() as f64).collect();
            let mut u = rng.gen::<f64>() * w.iter().sum::<f64>();
            let mut last = 0;
            for (i, &wi) in w.iter().enumerate() {
                if wi > 0.0 {
                    last = i;
                    u -= wi;
                    if u <= 0.0 {
                        return i;
                    }
                }
            }
            return last;
        }
        let mut idx: Vec<usize> = (0..logits.len()).collect();
        idx.sort_by(|&a, &b| logits[b].total_cmp(&logits[a]));
        let m = logits[idx[0]];
        let mut w: Vec<f64> = idx
            .iter()
            .map(|&i| (((logits[i] - m) / t) as f64).exp())
            .collect();
        let mut keep = idx.len();
        if self.top_k > 0 {
            keep = keep.min(self.top_k);
        }
        let z: f64 = w[..keep].iter().sum();
        if self.top_p < 1.0 {
            let mut acc = 0.0;
            for (k, wi) in w.iter().enumerate().take(keep) {
                acc += wi / z;
                if acc >= self.top_p {
                    keep = k + 1;
                    break;
                }
            }
        }
        // Protected indices past the cut move up, in order, behind it.
        let mut k = keep;
        for j in keep..idx.len() {
            if kept(idx[j]) {
                idx.swap(k, j);
                w.swap(k, j);
                k += 1;
            }
        }
        let keep = k;
        let z: f64 = w[..keep].iter().sum();
        let mut u = rng.gen::<f64>() * z;
        for k in 0..keep {
            u -= w[k];
            if u <= 0.0 {
                return idx[k];
            }
        }
        idx[keep - 1]
    }
}
