//! The frame-level motion model's configuration and token coding (beyond
//! the thesis; issue 16), shared by the trainer and the runtime.
//!
//! The thesis's flat GPT spends 43 sequential steps on every frame. This
//! model splits the work in two:
//! - a **global** causal transformer runs once per frame. Its input for a
//!   frame is the frame's 42 value tokens, each embedded (value + change
//!   from the previous frame), concatenated and projected; position 0 holds
//!   the conditioning (`<bos>` and the label tokens, summed);
//! - a small **local** causal transformer decodes the next frame's slots one
//!   by one from the global state. Slot `s` sees the previous slot's change,
//!   this slot's velocity (previous frame minus the one before) and its
//!   previous value.
//!
//! Continuity is built into the output, not left to be discovered: the
//! local head predicts the *change* from the previous frame's token at the
//! same slot (`2·radius + 1` classes) or an escape class, and a second head
//! gives the absolute bin, used for escapes and for a sequence's first
//! frame. The token vocabulary stays the thesis's: what is predicted is
//! still each slot's bin, only parametrised relative to the last one.
//! Log-losses are an honest upper bound: the absolute head's mass inside the
//! change window is never used, so the probabilities sum to at most one.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameConfig {
    /// Value bins per slot (the vocabulary's `bins`).
    pub bins: usize,
    /// Value slots per frame (the separator is implicit): 42 on SMPL-13.
    pub slots: usize,
    /// Largest change (in bins) the change head names; larger is an escape.
    pub radius: usize,
    /// Per-slot embedding width in the global input.
    pub d_emb: usize,
    pub d_global: usize,
    pub global_layers: usize,
    pub global_heads: usize,
    pub d_local: usize,
    pub local_layers: usize,
    pub local_heads: usize,
    /// Frames in the global context.
    pub max_frames: usize,
    /// The vocabulary's size: conditioning rows are vocabulary ids.
    pub vocab_size: usize,
    pub cond_kinds: Vec<String>,
    pub classes: Vec<(String, Vec<String>)>,
    pub ln_eps: f64,
    /// The conditioning also enters every frame's global input (through
    /// `g_cond_all`), not only position 0, so a label keeps steering a long
    /// window; trained with whole-conditioning dropout for guidance.
    #[serde(default)]
    pub cond_every: bool,
}

/// Whether slot `s` of a frame of `slots` value slots holds an angle (see
/// [`FrameConfig::wraps`]).
pub fn slot_wraps(s: usize, slots: usize) -> bool {
    s + 3 < slots
}

/// The signed step from bin `from` to bin `to` of an angle slot with
/// `bins` bins, the shorter way round (half a turn counts as −bins/2).
pub fn short_step(to: u32, from: u32, bins: usize) -> i64 {
    let bins = bins as i64;
    (to as i64 - from as i64 + bins / 2).rem_euclid(bins) - bins / 2
}

impl FrameConfig {
    /// Change classes the change head scores: `0..=2r` then the escape.
    pub fn rel_classes(&self) -> usize {
        2 * self.radius + 2
    }
    pub fn esc(&self) -> u32 {
        2 * self.radius as u32 + 1
    }
    /// "No previous frame" (a sequence's first frame).
    pub fn none(&self) -> u32 {
        2 * self.radius as u32 + 2
    }
    /// The local decoder's input before slot 0.
    pub fn start(&self) -> u32 {
        2 * self.radius as u32 + 3
    }
    /// Rows of the change embeddings (classes, none, start).
    pub fn change_rows(&self) -> usize {
        2 * self.radius + 4
    }

    /// Whether slot `s` holds an angle, whose bins wrap round (−π meets
    /// π): every joint's slot, not the root's last three (ground velocity
    /// x and z, and height), whose ends lie metres apart.
    pub fn wraps(&self, s: usize) -> bool {
        slot_wraps(s, self.slots)
    }

    /// The change code of going from bin `from` to bin `to`.
    pub fn change(&self, from: Option<u32>, to: u32) -> u32 {
        match from {
            None => self.none(),
            Some(a) => {
                let d = to as i64 - a as i64;
                if d.unsigned_abs() as usize <= self.radius {
                    (d + self.radius as i64) as u32
                } else {
                    self.esc()
                }
            }
        }
    }

    /// The bin a change code leads to from bin `from` (the inverse of
    /// [`FrameConfig::change`]; clamped into the bins, as the generator
    /// draws); None for the escape and the non-change codes.
    pub fn apply_change(&self, from: u32, code: u32) -> Option<u32> {
        if code >= self.esc() {
            return None;
        }
        let r = self.radius as i64;
        Some((from as i64 + code as i64 - r).clamp(0, self.bins as i64 - 1) as u32)
    }

    pub fn validate(&self, file: &str) -> Result<(), super::LmError> {
        let bad = |field: &str, reason: String| super::LmError::invalid(file, field, reason);
        super::check_heads(file, self.d_global, self.global_heads)?;
        super::check_heads(file, self.d_local, self.local_heads)?;
        if self.bins < 2 || self.slots == 0 || self.radius == 0 || self.d_emb == 0 {
            return Err(bad(
                "config",
                "bins ≥ 2, slots, radius and d_emb must be positive".into(),
            ));
        }
        if 2 * self.radius + 1 > self.bins {
            return Err(bad(
                "config.radius",
                format!("{} spans more than the {} bins", self.radius, self.bins),
            ));
        }
        if self.global_layers == 0 || self.local_layers == 0 || self.max_frames < 2 {
            return Err(bad(
                "config",
                "layers must be positive and max_frames at least 2".into(),
            ));
        }
        Ok(())
    }
}

/// Per-slot local inputs for decoding a frame after `p1` (and `p2` before
/// it): velocity codes and previous values (`bins` = none).
pub fn local_context(
    cfg: &FrameConfig,
    p1: Option<&[u32]>,
    p2: Option<&[u32]>,
) -> (Vec<u32>, Vec<u32>) {
    let mut vel = Vec::with_capacity(cfg.slots);
    let mut prev = Vec::with_capacity(cfg.slots);
    for s in 0..cfg.slots {
        match p1 {
            Some(a) => {
                vel.push(match p2 {
                    Some(b) => cfg.change(Some(b[s]), a[s]),
                    None => cfg.none(),
                });
                prev.push(a[s]);
            }
            None => {
                vel.push(cfg.none());
                prev.push(cfg.bins as u32);
            }
        }
    }
    (vel, prev)
}

/// Change codes of a frame against the previous one (global input).
pub fn frame_changes(cfg: &FrameConfig, frame: &[u32], p1: Option<&[u32]>) -> Vec<u32> {
    (0..cfg.slots)
        .map(|s| cfg.change(p1.map(|p| p[s]), frame[s]))
        .collect()
}

/// A small SMPL-13 frame config (360 bins, 42 slots, radius 8) for tests.
#[cfg(test)]
pub(crate) fn test_config() -> FrameConfig {
    FrameConfig {
        bins: 360,
        slots: 42,
        radius: 8,
        d_emb: 8,
        d_global: 32,
        global_layers: 1,
        global_heads: 2,
        d_local: 16,
        local_layers: 1,
        local_heads: 2,
        max_frames: 16,
        vocab_size: 400,
        cond_kinds: vec![],
        classes: vec![],
        ln_eps: 1e-5,
        cond_every: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> FrameConfig {
        test_config()
    }

    #[test]
    fn change_codes_cover_the_window_and_escape() {
        let c = cfg();
        assert_eq!(c.change(Some(100), 100), 8);
        assert_eq!(c.change(Some(100), 92), 0);
        assert_eq!(c.change(Some(100), 108), 16);
        assert_eq!(c.change(Some(100), 109), c.esc());
        assert_eq!(c.change(Some(100), 91), c.esc());
        assert_eq!(c.change(None, 5), c.none());
        assert_eq!(c.rel_classes(), 18);
        assert!(c.validate("t").is_ok());
    }

    #[test]
    fn local_context_reads_velocity_and_previous_value() {
        let c = cfg();
        let p2 = vec![10u32; 42];
        let p1 = vec![13u32; 42];
        let (v, p) = local_context(&c, Some(&p1), Some(&p2));
        assert_eq!(v[0], c.change(Some(10), 13));
        assert_eq!(p[5], 13);
        let (v, p) = local_context(&c, None, None);
        assert_eq!(v[0], c.none());
        assert_eq!(p[0], 360);
    }
}

/// The manifest of an exported frame model (`kind: motion-frame-lm`): two
/// graphs, the global step and the local step, each checked by hash.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameManifest {
    pub format: u32,
    pub kind: String,
    pub config: FrameConfig,
    pub vocabulary: crate::tokenize::vocab::Vocabulary,
    pub global_onnx: String,
    pub global_sha256: String,
    pub local_onnx: String,
    pub local_sha256: String,
    pub data: super::manifest::DataInfo,
    pub metrics: std::collections::BTreeMap<String, f64>,
    pub training: serde_json::Value,
    /// The `max_jump` a request gets when it names none, per label kind it
    /// asks for (the smallest of its kinds listed; none listed: the
    /// recommended sampling's). The corpora a model learns from move
    /// differently, and `choreo eval generate` scores the caps per corpus
    /// (docs/RESULTS.md, "Sampling defaults per label kind").
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub max_jump_by_kind: std::collections::BTreeMap<String, u32>,
    /// The `top_p`, `posture`, `draws`, `pace` and `jerk` a request gets when it names them not,
    /// per label kind it asks for (the first of its kinds, in name order,
    /// that lists the field; none: the recommended sampling's). `choreo
    /// eval generate` scores them per corpus (docs/RESULTS.md, "AIST++ dance: the
    /// posture with the whole nucleus").
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub sampling_by_kind: std::collections::BTreeMap<String, KindSampling>,
}

/// A label kind's sampling defaults ([`FrameManifest::sampling_by_kind`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KindSampling {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub top_p: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub posture: Option<f64>,
    /// Candidate frames a frame (`sampling.draws`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draws: Option<u32>,
    /// The pace hold's weight (`sampling.pace`), where `draws` leaves
    /// candidates to choose among.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace: Option<f64>,
    /// The jerk price (`sampling.jerk`), where `draws` leaves candidates
    /// to choose among.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jerk: Option<f64>,
    /// How far the posture pull eases off in a slowing clip
    /// (`sampling.ease`), where there is a pull.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ease: Option<f64>,
    /// How strongly the joints follow the labels' real takes
    /// (`sampling.matching`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub matching: Option<f64>,
    /// The skate price (`sampling.skate`), where `draws` leaves
    /// candidates to choose among.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skate: Option<f64>,
}

pub const FRAME_KIND: &str = "motion-frame-lm";
pub const GLOBAL_ONNX: &str = "global.onnx";
pub const LOCAL_ONNX: &str = "local.onnx";
/// The local graph's batch dimension, a symbol: the
/// candidate frames of `sampling.draws` decoded side by side, one run a
/// slot. Graphs exported before have a batch of 1 (the candidates then
/// run one after another).
pub const LOCAL_BATCH: &str = "batch";

/// Input names of the global step graph, in order.
pub fn global_inputs(cfg: &FrameConfig) -> Vec<String> {
    let mut v: Vec<String> = ["val", "chg", "cond", "is_cond", "pos", "bias"]
        .map(String::from)
        .to_vec();
    for l in 0..cfg.global_layers {
        v.push(format!("cache_k_{l}"));
        v.push(format!("cache_v_{l}"));
    }
    v
}

/// Output names of the global step graph, in order.
pub fn global_outputs(cfg: &FrameConfig) -> Vec<String> {
    let mut v = vec!["h".to_string()];
    for (k, _) in &cfg.classes {
        v.push(format!("cls_{k}"));
    }
    for l in 0..cfg.global_layers {
        v.push(format!("k_{l}"));
        v.push(format!("v_{l}"));
    }
    v
}

/// Input names of the local step graph, in order.
pub fn local_inputs(cfg: &FrameConfig) -> Vec<String> {
    let mut v: Vec<String> = ["ctx", "inp", "vel", "prev", "slot", "bias"]
        .map(String::from)
        .to_vec();
    for l in 0..cfg.local_layers {
        v.push(format!("cache_k_{l}"));
        v.push(format!("cache_v_{l}"));
    }
    v
}

/// Output names of the local step graph, in order.
pub fn local_outputs(cfg: &FrameConfig) -> Vec<String> {
    let mut v = vec!["rel".to_string(), "abs".to_string()];
    for l in 0..cfg.local_layers {
        v.push(format!("k_{l}"));
        v.push(format!("v_{l}"));
    }
    v
}

impl FrameManifest {
    /// Reads and checks a frame model's manifest and both graphs' hashes;
    /// returns the manifest and the two graphs' bytes.
    pub fn load(
        path: &std::path::Path,
    ) -> Result<(FrameManifest, Vec<u8>, Vec<u8>), super::LmError> {
        let (file, name, m): (std::path::PathBuf, String, FrameManifest) =
            super::manifest::read_manifest(path)?;
        if m.format != super::manifest::MANIFEST_FORMAT {
            return Err(super::LmError::invalid(
                &name,
                "format",
                format!(
                    "{} (this build reads format {})",
                    m.format,
                    super::manifest::MANIFEST_FORMAT
                ),
            ));
        }
        if m.kind != FRAME_KIND {
            return Err(super::LmError::invalid(
                &name,
                "kind",
                format!("{:?}, want {FRAME_KIND:?}", m.kind),
            ));
        }
        m.config.validate(&name)?;
        m.vocabulary
            .validate()
            .map_err(|e| super::LmError::invalid(&name, "vocabulary", e.to_string()))?;
        if m.vocabulary.size() != m.config.vocab_size
            || m.vocabulary.bins != m.config.bins
            || m.vocabulary.frame_len() != m.config.slots + 1
        {
            return Err(super::LmError::invalid(
                &name,
                "config",
                format!(
                    "vocab_size {}, bins {}, slots {} do not match the vocabulary ({} tokens, {} bins, {} value slots)",
                    m.config.vocab_size,
                    m.config.bins,
                    m.config.slots,
                    m.vocabulary.size(),
                    m.vocabulary.bins,
                    m.vocabulary.frame_len() - 1
                ),
            ));
        }
        for (kind, &j) in &m.max_jump_by_kind {
            if !m.vocabulary.labels.contains_key(kind) {
                return Err(super::LmError::invalid(
                    &name,
                    "max_jump_by_kind",
                    format!("'{kind}' is not a label kind of the vocabulary"),
                ));
            }
            if !(1..=180).contains(&j) {
                return Err(super::LmError::invalid(
                    &name,
                    "max_jump_by_kind",
                    format!("{kind}: {j} (want 1 to 180 bins)"),
                ));
            }
        }
        for (kind, d) in &m.sampling_by_kind {
            let field = format!("sampling_by_kind.{kind}");
            if !m.vocabulary.labels.contains_key(kind) {
                return Err(super::LmError::invalid(
                    &name,
                    field,
                    "not a label kind of the vocabulary",
                ));
            }
            if let Some(p) = d.top_p.filter(|p| !(*p > 0.0 && *p <= 1.0)) {
                return Err(super::LmError::invalid(
                    &name,
                    format!("{field}.top_p"),
                    format!("{p} (want 0 < top_p ≤ 1)"),
                ));
            }
            if let Some(w) = d.posture.filter(|w| !(0.0..=10.0).contains(w)) {
                return Err(super::LmError::invalid(
                    &name,
                    format!("{field}.posture"),
                    format!("{w} (want 0 to 10)"),
                ));
            }
            let most = super::sampling::MAX_DRAWS;
            if let Some(n) = d.draws.filter(|n| !(1..=most).contains(n)) {
                return Err(super::LmError::invalid(
                    &name,
                    format!("{field}.draws"),
                    format!("{n} (want 1 to {most})"),
                ));
            }
            for (key, v, most) in [
                ("pace", d.pace, 100.0),
                ("jerk", d.jerk, 100.0),
                ("ease", d.ease, 10.0),
                ("matching", d.matching, 10.0),
            ] {
                if let Some(a) = v.filter(|a| !(0.0..=most).contains(a)) {
                    return Err(super::LmError::invalid(
                        &name,
                        format!("{field}.{key}"),
                        format!("{a} (want 0 to {most})"),
                    ));
                }
            }
        }
        let (_, g) =
            super::manifest::read_onnx_checked(&file, &name, &m.global_onnx, &m.global_sha256)?;
        let (_, l) =
            super::manifest::read_onnx_checked(&file, &name, &m.local_onnx, &m.local_sha256)?;
        Ok((m, g, l))
    }

    pub fn save(&self, dir: &std::path::Path) -> Result<(), super::LmError> {
        let p = dir.join(super::manifest::MANIFEST_FILE);
        let text = serde_json::to_string_pretty(self).expect("manifest serialises");
        std::fs::write(&p, text + "\n").map_err(|e| super::LmError::Io {
            file: p.display().to_string(),
            reason: e.to_string(),
        })
    }
}
