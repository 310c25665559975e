//! Label postures: per label value, where each value slot of a frame
//! sits in that label's training sequences (a mean bin μ and a spread σ,
//! the shorter way round for angles). At sampling, `sampling.posture`
//! w > 0 adds `−w Σ_labels d(b, μ)² / (2σ²)` to every bin b's logit: the
//! labels' Gaussian posture as a second expert beside the model, a pull of
//! each joint toward where the asked-for labels hold it, which the frame
//! model's own conditioning barely gives (docs/RESULTS.md, "What the labels are
//! worth"): its clips start in the exemplar's style and drift to the
//! corpus's average pose within seconds.
//!
//! Not pulled slot by slot: the root joint's rotation (it holds the
//! heading, which a take chooses freely) and the root's ground velocity
//! (world-frame travel); the root's height is. The root's rotation is
//! pulled through its tilt instead: the angle between the body's up axis
//! and the vertical, whatever the heading, has a mean and spread per label
//! like a slot's, and each root component's bins are scored by the tilt
//! they would give beside the components already drawn (the previous
//! frame's for those still to come). Without it a clip can bow forward to
//! lying and, its long context seeing itself lie, stay there.
//!
//! A label may also have pose clusters (`posture/clusters.rs`): then each frame is
//! pulled toward the clusters by their responsibility for the previous
//! frame, so a style's bow, walk and raised hand each keep their own pose.
//!
//! `postures.json` in a frame model's folder, written by `choreo postures`
//! from the training side of corpus folders.

use super::LmError;
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use crate::tokenize::UniformBins;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

mod clusters;
use clusters::cluster;
pub use clusters::Component;

pub const FILE: &str = "postures.json";

/// The narrowest spread a slot's pull uses (bins): a slot a label never
/// moves would otherwise pin it.
pub const MIN_SPREAD: f64 = 3.0;

/// The narrowest spread of the tilt pull (degrees).
pub const MIN_TILT_SPREAD: f64 = 2.0;

/// One slot under one label: mean bin and spread (bins), or none where
/// the slot is not pulled.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SlotStat {
    pub mean: f64,
    pub spread: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Postures {
    /// Bins per slot and slots per frame (checked at load).
    pub bins: usize,
    pub slots: usize,
    /// Frames each label value's figures come from.
    pub frames: BTreeMap<String, BTreeMap<String, usize>>,
    /// kind → value → one entry per slot (`null`: not pulled).
    pub labels: BTreeMap<String, BTreeMap<String, Vec<Option<SlotStat>>>>,
    /// kind → value → the root's tilt from the vertical (degrees): mean
    /// and spread. Absent in files written before session 24 (no tilt
    /// pull then).
    #[serde(default)]
    pub tilt: BTreeMap<String, BTreeMap<String, SlotStat>>,
    /// kind → value → pose clusters of that label's frames (`choreo
    /// postures --clusters KIND=K`): where a label has them, the pull
    /// follows the cluster the previous frame sits in rather than the
    /// label's one mean pose. Absent in files written before session 32.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub components: BTreeMap<String, BTreeMap<String, Vec<Component>>>,
}

/// The angle (degrees) between the vertical (+y) and the up axis of a body
/// turned by the axis-angle `aa`: the (y, y) entry of its rotation matrix
/// is that angle's cosine.
pub fn up_tilt_degrees(aa: [f64; 3]) -> f64 {
    let th = (aa[0] * aa[0] + aa[1] * aa[1] + aa[2] * aa[2]).sqrt();
    if th < 1e-12 {
        return 0.0;
    }
    let ay = aa[1] / th;
    let c = th.cos();
    (c + (1.0 - c) * ay * ay)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// The root's tilt (degrees) in a frame's tokens (slots 0–2 the root
/// joint's axis-angle, decoded by the vocabulary's angle bins).
pub fn frame_tilt(frame: &[u32], angles: &UniformBins) -> f64 {
    up_tilt_degrees([0, 1, 2].map(|i| angles.decode(frame[i])))
}

use super::frame::slot_wraps as wraps;

/// Whether slot `s` of `slots` is pulled: a joint angle but not the root
/// joint's rotation (slots 0–2), or the root's height (the last slot);
/// not the root's ground velocity (the two slots before it).
pub(super) fn pulled(s: usize, slots: usize) -> bool {
    (s >= 3 && wraps(s, slots)) || s + 1 == slots
}

impl Postures {
    /// Fits every (kind, value) of `kinds` the vocabulary knows from the
    /// sequences' frame tokens (`frame_len` a frame, separator last).
    /// `clusters`: label kind → pose clusters to fit per value of it (a
    /// kind not listed, or listed with fewer than 2, gets none).
    pub fn fit(
        sequences: &[(String, Labels, Vec<u32>)],
        vocab: &Vocabulary,
        kinds: &[String],
        clusters: &BTreeMap<String, usize>,
    ) -> Postures {
        let fl = vocab.frame_len();
        let slots = fl - 1;
        let bins = vocab.bins;
        let angles = vocab.angle_bins();
        let mut labels = BTreeMap::new();
        let mut frames = BTreeMap::new();
        let mut tilt = BTreeMap::new();
        let mut components = BTreeMap::new();
        for k in kinds {
            let Some(values) = vocab.labels.get(k) else {
                continue;
            };
            for v in values {
                let seqs: Vec<&Vec<u32>> = sequences
                    .iter()
                    .filter(|(_, l, _)| l.get(k) == Some(v))
                    .map(|s| &s.2)
                    .collect();
                let n: usize = seqs.iter().map(|t| t.len() / fl).sum();
                if n == 0 {
                    continue;
                }
                let stats = (0..slots)
                    .map(|s| {
                        pulled(s, slots).then(|| {
                            let xs = seqs
                                .iter()
                                .flat_map(|t| t.chunks_exact(fl).map(move |f| f[s] as f64));
                            slot_stat(xs, bins as f64, wraps(s, slots))
                        })
                    })
                    .collect();
                labels
                    .entry(k.clone())
                    .or_insert_with(BTreeMap::new)
                    .insert(v.clone(), stats);
                let tilts = seqs
                    .iter()
                    .flat_map(|t| t.chunks_exact(fl).map(|f| frame_tilt(f, &angles)));
                let mut st = slot_stat(tilts, 360.0, false);
                st.spread = st.spread.max(MIN_TILT_SPREAD);
                tilt.entry(k.clone())
                    .or_insert_with(BTreeMap::new)
                    .insert(v.clone(), st);
                frames
                    .entry(k.clone())
                    .or_insert_with(BTreeMap::new)
                    .insert(v.clone(), n);
                let kk = clusters.get(k).copied().unwrap_or(0);
                if kk > 1 {
                    let fr: Vec<&[u32]> = seqs
                        .iter()
                        .flat_map(|t| t.chunks_exact(fl).map(|f| &f[..slots]))
                        .collect();
                    components
                        .entry(k.clone())
                        .or_insert_with(BTreeMap::new)
                        .insert(v.clone(), cluster(&fr, kk, bins as f64, slots));
                }
            }
        }
        Postures {
            bins,
            slots,
            frames,
            labels,
            tilt,
            components,
        }
    }

    /// The postures of a model folder, if it has them; a file that does
    /// not fit the model (bins, slots, a label it does not know, a slot
    /// list of the wrong length or a spread that is not positive) is an
    /// error naming the field.
    pub fn load(dir: &Path, vocab: &Vocabulary) -> Result<Option<Postures>, LmError> {
        let Some((p, name)) = super::read_optional_json::<Postures>(&dir.join(FILE), "postures")?
        else {
            return Ok(None);
        };
        p.check(vocab)
            .map_err(|(f, why)| LmError::invalid(&name, f, why))?;
        Ok(Some(p))
    }

    fn check(&self, vocab: &Vocabulary) -> Result<(), (String, String)> {
        if self.bins != vocab.bins {
            return Err((
                "bins".into(),
                format!("{} but the model has {}", self.bins, vocab.bins),
            ));
        }
        if self.slots + 1 != vocab.frame_len() {
            return Err((
                "slots".into(),
                format!(
                    "{} but the model's frames have {}",
                    self.slots,
                    vocab.frame_len() - 1
                ),
            ));
        }
        for (k, vs) in &self.labels {
            let known = vocab.labels.get(k);
            for (v, stats) in vs {
                let field = format!("labels.{k}.{v}");
                if !known.is_some_and(|s| s.contains(v)) {
                    return Err((field, "a label the model does not know".into()));
                }
                self.check_slots(&field, &field, stats)?;
            }
        }
        for (k, vs) in &self.components {
            for (v, cs) in vs {
                let field = format!("components.{k}.{v}");
                if !vocab.labels.get(k).is_some_and(|s| s.contains(v)) {
                    return Err((field, "a label the model does not know".into()));
                }
                for (i, c) in cs.iter().enumerate() {
                    let field = format!("{field}[{i}]");
                    if !(c.weight.is_finite() && c.weight > 0.0 && c.weight <= 1.0) {
                        return Err((field, format!("weight {} (want 0 < w ≤ 1)", c.weight)));
                    }
                    self.check_slots(&field, &format!("{field}.slots"), &c.slots)?;
                }
            }
        }
        for (k, vs) in &self.tilt {
            for (v, st) in vs {
                let field = format!("tilt.{k}.{v}");
                if !vocab.labels.get(k).is_some_and(|s| s.contains(v)) {
                    return Err((field, "a label the model does not know".into()));
                }
                let ok =
                    st.spread.is_finite() && st.spread > 0.0 && (0.0..=180.0).contains(&st.mean);
                if !ok {
                    return Err((
                        field,
                        format!(
                            "mean {} spread {} (want 0–180 degrees and a positive spread)",
                            st.mean, st.spread
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// One slot list (a label's or a cluster's): one entry per slot (else
    /// an error naming `field`), each a bin and a positive spread (else
    /// one naming `per_slot[s]`).
    fn check_slots(
        &self,
        field: &str,
        per_slot: &str,
        stats: &[Option<SlotStat>],
    ) -> Result<(), (String, String)> {
        if stats.len() != self.slots {
            return Err((
                field.to_string(),
                format!("{} slots, want {}", stats.len(), self.slots),
            ));
        }
        for (s, st) in stats.iter().enumerate() {
            if let Some(st) = st {
                let ok = st.spread.is_finite()
                    && st.spread > 0.0
                    && st.mean.is_finite()
                    && (0.0..self.bins as f64).contains(&st.mean);
                if !ok {
                    return Err((
                        format!("{per_slot}[{s}]"),
                        format!(
                            "mean {} spread {} (want a bin and a positive spread)",
                            st.mean, st.spread
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The pull for `labels`, times `weight`: per slot, every bin's logit
    /// offset `−w Σ_labels d(b, μ)² / (2σ²)` (labels without a posture add
    /// nothing). None when no asked-for label has one.
    pub fn pull(&self, labels: &Labels, weight: f64) -> Option<Pull> {
        let stats: Vec<&Vec<Option<SlotStat>>> = labels
            .iter()
            .filter_map(|(k, v)| self.labels.get(k)?.get(v))
            .collect();
        if stats.is_empty() {
            return None;
        }
        let offsets = self.offsets_of(&stats, weight);
        let clustered = |k: &String, v: &String| {
            self.components
                .get(k)
                .and_then(|c| c.get(v))
                .is_some_and(|c| !c.is_empty())
        };
        let unclustered: Vec<&Vec<Option<SlotStat>>> = labels
            .iter()
            .filter(|(k, v)| !clustered(k, v))
            .filter_map(|(k, v)| self.labels.get(k)?.get(v))
            .collect();
        let plain = self.offsets_of(&unclustered, weight);
        let tilt = labels
            .iter()
            .filter_map(|(k, v)| self.tilt.get(k)?.get(v).cloned())
            .collect();
        let mixtures = labels
            .iter()
            .filter(|(k, v)| clustered(k, v))
            .filter_map(|(k, v)| self.components.get(k)?.get(v))
            .map(|cs| {
                cs.iter()
                    .map(|c| (c.weight.max(1e-9).ln(), self.offsets_of(&[&c.slots], 1.0)))
                    .collect()
            })
            .collect();
        Some(Pull {
            offsets,
            plain,
            tilt,
            weight,
            angles: UniformBins::angles(self.bins),
            mixtures,
        })
    }

    /// Per slot, every bin's `−w Σ d(b, μ)² / (2σ²)` over `stats`.
    fn offsets_of(&self, stats: &[&Vec<Option<SlotStat>>], weight: f64) -> Vec<Vec<f32>> {
        let bins = self.bins as f64;
        (0..self.slots)
            .map(|s| {
                (0..self.bins)
                    .map(|b| {
                        let mut x = 0.0;
                        for st in stats.iter().filter_map(|l| l[s].as_ref()) {
                            let mut d = (b as f64 - st.mean).abs();
                            if wraps(s, self.slots) {
                                d = d.min(bins - d);
                            }
                            let sp = st.spread.max(MIN_SPREAD);
                            x -= d * d / (2.0 * sp * sp);
                        }
                        (weight * x) as f32
                    })
                    .collect()
            })
            .collect()
    }
}

/// The asked-for labels' postures as logit offsets: `slots` rows of `bins`,
/// and their root tilts.
#[derive(Clone, Debug)]
pub struct Pull {
    /// Every asked-for label's one mean pose (a clip's first frame, with
    /// no previous frame to place it in a cluster).
    pub offsets: Vec<Vec<f32>>,
    /// The labels without pose clusters only (added to the clusters').
    plain: Vec<Vec<f32>>,
    tilt: Vec<SlotStat>,
    weight: f64,
    angles: UniformBins,
    /// Per asked-for label with pose clusters: (log share, unweighted
    /// offsets) per cluster.
    mixtures: Vec<Vec<(f64, Vec<Vec<f32>>)>>,
}

impl Pull {
    /// The pull for the frame after `prev` (None: a clip's first frame).
    /// For labels with pose clusters, each cluster's responsibility for
    /// the previous frame (its share times its Gaussian, normalised per
    /// label) is worked out here, once a frame, not once a slot.
    pub fn for_frame<'a>(&'a self, prev: Option<&'a [u32]>, scale: f32) -> FramePull<'a> {
        let resp = match prev {
            Some(p) => self
                .mixtures
                .iter()
                .map(|mix| {
                    let ll: Vec<f64> = mix
                        .iter()
                        .map(|(lw, off)| {
                            lw + off
                                .iter()
                                .zip(p)
                                .map(|(o, &b)| o.get(b as usize).copied().unwrap_or(0.0) as f64)
                                .sum::<f64>()
                        })
                        .collect();
                    let m = ll.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                    let z: f64 = ll.iter().map(|l| (l - m).exp()).sum();
                    ll.iter()
                        .map(|l| ((l - m).exp() / z * self.weight) as f32 * scale)
                        .collect()
                })
                .collect(),
            None => Vec::new(),
        };
        FramePull {
            pull: self,
            prev,
            resp,
            scale,
        }
    }
}

/// [`Pull`] for one frame ([`Pull::for_frame`]).
pub struct FramePull<'a> {
    pull: &'a Pull,
    prev: Option<&'a [u32]>,
    /// Per clustered label, each cluster's responsibility for the
    /// previous frame times the pull's weight (empty without a previous
    /// frame or clusters).
    resp: Vec<Vec<f32>>,
    /// The whole pull's scale this frame (1: as the request set it).
    scale: f32,
}

impl<'a> FramePull<'a> {
    /// Slot `s`'s offsets: for a joint slot (s ≥ 3) of a label with pose
    /// clusters and a previous frame, the clusters' offsets weighted by
    /// their responsibility for the previous frame, beside the other
    /// labels' mean poses; for a root rotation component (s < 3) with tilt
    /// figures, every bin's `−w Σ_labels (t − μ)² / (2σ²)`, t the tilt of
    /// the axis-angle made of that bin, the components this frame has
    /// drawn (`drawn[..s]`) and the previous frame's for the rest (zero
    /// without one); otherwise the slot's fixed offsets.
    ///
    /// `read`: the frame generator's change radius and `max_jump`. With a
    /// previous frame, a draw reads a root component's offsets only in
    /// the change window (within the radius of the previous bin) and
    /// where an escape may land (within `max_jump` of it, the shorter way
    /// round; anywhere when it is 0: `frame_draw::draw`), so the tilt is
    /// worked out only there; the other bins keep the fixed offsets,
    /// which no draw reads.
    pub fn slot(&self, s: usize, drawn: &[u32], read: Option<(usize, u32)>) -> Cow<'a, [f32]> {
        let pl: &'a Pull = self.pull;
        if s >= 3 && !self.resp.is_empty() {
            let mut out: Vec<f32> = pl.plain[s].iter().map(|x| x * self.scale).collect();
            for (mix, rs) in pl.mixtures.iter().zip(&self.resp) {
                for ((_, off), &r) in mix.iter().zip(rs) {
                    for (o, x) in out.iter_mut().zip(&off[s]) {
                        *o += r * x;
                    }
                }
            }
            return Cow::Owned(out);
        }
        if s >= 3 || pl.tilt.is_empty() {
            if self.scale == 1.0 {
                return Cow::Borrowed(&pl.offsets[s]);
            }
            return Cow::Owned(pl.offsets[s].iter().map(|x| x * self.scale).collect());
        }
        let mut aa = [0.0; 3];
        for (i, a) in aa.iter_mut().enumerate() {
            let b = if i < s {
                drawn.get(i)
            } else {
                self.prev.and_then(|p| p.get(i))
            };
            *a = b.map_or(0.0, |&b| pl.angles.decode(b));
        }
        let (bins, circular) = (pl.angles.bins as i64, wraps(s, pl.offsets.len()));
        let last = self.prev.and_then(|p| p.get(s));
        let read_bin = |b: i64| match (read, last) {
            (Some((r0, jump)), Some(&p)) => {
                super::frame_draw::reads_bin(b, p as i64, (r0 as i64, jump as i64), bins, circular)
            }
            _ => true,
        };
        Cow::Owned(
            (0..pl.angles.bins)
                .map(|b| {
                    if !read_bin(b as i64) {
                        return pl.offsets[s][b] * self.scale;
                    }
                    aa[s] = pl.angles.decode(b as u32);
                    let t = up_tilt_degrees(aa);
                    let x: f64 = pl
                        .tilt
                        .iter()
                        .map(|st| {
                            let d = t - st.mean;
                            -d * d / (2.0 * st.spread * st.spread)
                        })
                        .sum();
                    (pl.offsets[s][b] + (pl.weight * x) as f32) * self.scale
                })
                .collect(),
        )
    }
}

/// Mean and spread of a slot's bins; for an angle the circular mean (on
/// the circle of `bins`) and the spread √(−2 ln R) in bins.
fn slot_stat(xs: impl Iterator<Item = f64>, bins: f64, wraps: bool) -> SlotStat {
    let (mut n, mut a, mut b) = (0.0, 0.0, 0.0);
    if wraps {
        let w = std::f64::consts::TAU / bins;
        for x in xs {
            n += 1.0;
            a += (x * w).cos();
            b += (x * w).sin();
        }
        let r = ((a * a + b * b).sqrt() / n).clamp(1e-12, 1.0);
        let mean = b.atan2(a).rem_euclid(std::f64::consts::TAU) / w;
        SlotStat {
            mean: if mean >= bins { 0.0 } else { mean },
            spread: ((-2.0 * r.ln()).sqrt() / w).max(MIN_SPREAD),
        }
    } else {
        for x in xs {
            n += 1.0;
            a += x;
            b += x * x;
        }
        let mean = a / n;
        SlotStat {
            mean,
            spread: (b / n - mean * mean).max(0.0).sqrt().max(MIN_SPREAD),
        }
    }
}

#[cfg(test)]
mod tests;
