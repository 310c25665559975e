//! Generation and classification on a loaded model.
//!
//! [`Generator`] produces one frame (43 tokens) per call: prompt slots are
//! forced from the caller's motion (thesis §4.6, Fig. 4.11), the rest are
//! sampled from the model restricted to the tokens the slot allows.
//! Consecutive forced tokens are fed in one step, and every step reuses the
//! cached keys and values. When the window is full, the oldest half is
//! dropped and the rest re-encoded (one step), so a stream can run for as
//! long as the caller wants. One-shot generation and streaming call the same
//! `next_frame`, so with one seed they give the same frames.

use super::runtime::{Kv, LmSession};
use super::{LmError, ModelConfig};
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::sync::Arc;

use super::sampling::Sampling;

/// Which of a frame's slots a joint prompt fixes: three per named joint;
/// naming the root (`pelvis`) also fixes the root's velocity and height
/// slots, so the prompt carries the path through space. Names match
/// without regard to case (`right_elbow` = `Right_Elbow`).
pub fn prompt_slots(vocab: &Vocabulary, joints: &[String]) -> Result<Vec<bool>, LmError> {
    let fl = vocab.frame_len();
    let mut slots = vec![false; fl];
    for name in joints {
        let k = vocab
            .joints
            .iter()
            .position(|j| j.eq_ignore_ascii_case(name))
            .ok_or_else(|| {
                LmError::invalid(
                    "request",
                    "prompt.joints",
                    format!(
                        "unknown joint {name:?} (the model's joints: {})",
                        vocab.joints.join(", ")
                    ),
                )
            })?;
        for s in 3 * k..3 * k + 3 {
            slots[s] = true;
        }
        if k == 0 {
            let nj = vocab.joints.len();
            for s in 3 * nj..3 * nj + 3 {
                slots[s] = true;
            }
        }
    }
    Ok(slots)
}

/// Frame tokens with the prompt's slots kept and the rest left free.
pub fn forced_frames(tokens: &[u32], slots: &[bool]) -> Vec<Vec<Option<u32>>> {
    tokens
        .chunks_exact(slots.len())
        .map(|f| {
            f.iter()
                .zip(slots)
                .map(|(&t, &on)| on.then_some(t))
                .collect()
        })
        .collect()
}

/// The conditioning prefix (`<bos>` + one token per label) of a request's
/// labels; a kind the model is not conditioned on, or a value its
/// vocabulary lacks, is an error naming it. Shared by both model kinds.
pub fn request_prefix(
    vocab: &Vocabulary,
    cond_kinds: &[String],
    labels: &Labels,
) -> Result<Vec<u32>, LmError> {
    if let Some(k) = labels.keys().find(|k| !cond_kinds.contains(k)) {
        return Err(LmError::invalid(
            "request",
            format!("labels.{k}"),
            format!(
                "the model is not conditioned on {k:?} (it takes: {})",
                cond_kinds.join(", ")
            ),
        ));
    }
    vocab.prefix(labels).map_err(|e| match e {
        crate::motion::MotionError::Invalid { field, reason, .. } => {
            LmError::invalid("request", format!("labels ({field})"), reason)
        }
        other => LmError::Runtime(other.to_string()),
    })
}

/// Where a clip of `frames` frames is read for classification: windows of
/// `w` frames overlapping by half, or `max_windows` of them spread evenly
/// when there would be more. Shared by both model kinds.
pub fn classify_starts(frames: usize, w: usize, max_windows: usize) -> Vec<usize> {
    let hop = (w / 2).max(1);
    let starts: Vec<usize> = (0..=frames - w).step_by(hop).collect();
    if starts.len() <= max_windows.max(1) {
        return starts;
    }
    let n = max_windows.max(1);
    (0..n).map(|i| i * (frames - w) / (n - 1).max(1)).collect()
}

/// Adds `weight` × softmax(`logits`) to `acc`.
pub fn add_softmax(acc: &mut [f64], logits: &[f32], weight: f64) {
    let mx = logits.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    let e: Vec<f64> = logits.iter().map(|&x| ((x - mx) as f64).exp()).collect();
    let z: f64 = e.iter().sum();
    for (a, p) in acc.iter_mut().zip(&e) {
        *a += weight * p / z;
    }
}

/// Class probabilities per kind, each sorted by probability.
pub fn class_table(
    classes: &[(String, Vec<String>)],
    acc: Vec<Vec<f64>>,
) -> Vec<(String, Vec<(String, f64)>)> {
    classes
        .iter()
        .zip(acc)
        .map(|((k, values), a)| {
            let mut v: Vec<(String, f64)> = values.iter().cloned().zip(a).collect();
            v.sort_by(|x, y| y.1.total_cmp(&x.1));
            (k.clone(), v)
        })
        .collect()
}

/// A running generation: the model, the prefix, the frames in the window,
/// the key/value cache and the random state.
pub struct Generator {
    session: Arc<LmSession>,
    prefix: Vec<u32>,
    /// Frame tokens in the current window (whole frames, fed or pending).
    window: Vec<u32>,
    /// Tokens at the end of `window` (or the prefix) not yet fed.
    pending: usize,
    prefix_pending: bool,
    kv: Kv,
    last_logits: Vec<f32>,
    rng: StdRng,
    sampling: Sampling,
    /// Frames generated so far.
    pub produced: usize,
}

impl Generator {
    /// Starts from `<bos>` and the given labels (unknown kinds or values
    /// are errors naming them), optionally continuing `seed_tokens` (whole
    /// frames; only the last half-window is kept).
    pub fn new(
        session: Arc<LmSession>,
        labels: &Labels,
        seed_tokens: &[u32],
        sampling: Sampling,
    ) -> Result<Generator, LmError> {
        sampling.validate()?;
        if sampling.posture > 0.0 {
            return Err(LmError::invalid(
                "request",
                "sampling.posture",
                "the flat GPT cannot pull toward label postures (the frame model can; 0 = off)",
            ));
        }
        if sampling.context > 0 {
            return Err(LmError::invalid(
                "request",
                "sampling.context",
                "the flat GPT reads its whole 8-frame window (the frame model can read less; 0 = whole)",
            ));
        }
        let m = &session.manifest;
        let cfg = &m.config;
        let prefix = request_prefix(&m.vocabulary, &cfg.cond_kinds, labels)?;
        let fl = cfg.frame_len;
        if seed_tokens.len() % fl != 0 {
            return Err(LmError::invalid("request", "seed", "not whole frames"));
        }
        let keep = (cfg.max_frames / 2).max(1) * fl;
        let window = seed_tokens[seed_tokens.len().saturating_sub(keep)..].to_vec();
        let kv = Kv::empty(cfg);
        Ok(Generator {
            pending: window.len(),
            window,
            prefix,
            prefix_pending: true,
            kv,
            last_logits: Vec::new(),
            rng: StdRng::seed_from_u64(sampling.seed),
            sampling,
            session,
            produced: 0,
        })
    }

    fn cfg(&self) -> &ModelConfig {
        &self.session.manifest.config
    }

    /// Feeds whatever is pending (prefix and/or frame tokens) in one step.
    fn flush(&mut self) -> Result<(), LmError> {
        let session = self.session.clone();
        let cfg = session.config();
        let pl = self.prefix.len();
        let mut toks = Vec::new();
        let mut pos = Vec::new();
        if self.prefix_pending {
            toks.extend_from_slice(&self.prefix);
            pos.extend((0..pl).map(|i| cfg.prefix_pos(i)));
        }
        let start = self.window.len() - self.pending;
        toks.extend_from_slice(&self.window[start..]);
        pos.extend((start..self.window.len()).map(|j| cfg.frame_pos(pl, j)));
        if toks.is_empty() {
            return Ok(());
        }
        let kv = std::mem::replace(&mut self.kv, Kv::empty(cfg));
        let (out, kv) = self.session.step(&toks, &pos, kv)?;
        self.kv = kv;
        let v = cfg.vocab_size;
        self.last_logits = out.logits[(toks.len() - 1) * v..].to_vec();
        self.prefix_pending = false;
        self.pending = 0;
        Ok(())
    }

    /// Drops the oldest half of a full window and re-encodes the rest.
    fn slide(&mut self) {
        let session = self.session.clone();
        let cfg = session.config();
        let keep = (cfg.max_frames / 2).max(1) * cfg.frame_len;
        let cut = self.window.len() - keep;
        self.window.drain(..cut);
        self.kv = Kv::empty(cfg);
        self.prefix_pending = true;
        self.pending = self.window.len();
    }

    /// The next frame's 43 tokens. `forced[s]` fixes slot `s` (a joint
    /// prompt); the separator is always forced. A forced token the slot
    /// does not allow is an error naming the slot.
    pub fn next_frame(&mut self, forced: &[Option<u32>]) -> Result<Vec<u32>, LmError> {
        let fl = self.cfg().frame_len;
        if forced.len() != fl {
            return Err(LmError::invalid(
                "request",
                "prompt",
                format!("{} slots, want {fl}", forced.len()),
            ));
        }
        if self.window.len() / fl >= self.cfg().max_frames {
            self.slide();
        }
        let session = self.session.clone();
        let vocab = &session.manifest.vocabulary;
        let mut frame = Vec::with_capacity(fl);
        for (s, f) in forced.iter().enumerate() {
            let allowed = vocab.allowed(s);
            let tok = match (s + 1 == fl, f) {
                (true, _) => vocab.sep(),
                (false, Some(t)) => {
                    if !allowed.contains(t) {
                        return Err(LmError::invalid(
                            "request",
                            format!("prompt slot {s}"),
                            format!("token {t} is not a value token"),
                        ));
                    }
                    *t
                }
                (false, None) => {
                    if self.pending > 0 || self.prefix_pending {
                        self.flush()?;
                    }
                    let row = &self.last_logits[allowed.start as usize..allowed.end as usize];
                    allowed.start + self.sampling.draw(row, &mut self.rng) as u32
                }
            };
            frame.push(tok);
            self.window.push(tok);
            self.pending += 1;
        }
        self.produced += 1;
        Ok(frame)
    }
}

/// Decodes a stream frame by frame exactly as
/// [`Vocabulary::decode_motion`] decodes the whole: the root's ground
/// position integrates the velocity slots from the second frame on, or,
/// [`FrameDecoder::root_from_feet`], is rebuilt from foot contact (and the
/// feet set on the floor) as [`crate::motion::contact::lock_feet`] rebuilds
/// a whole clip's.
pub struct FrameDecoder {
    x: f64,
    z: f64,
    frames: usize,
    feet: Option<crate::motion::contact::FootLock>,
    /// The legs' IK and the skeleton it solves on.
    pin: Option<(crate::motion::foot_pin::FootPin, crate::motion::Skeleton)>,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    pub fn new() -> FrameDecoder {
        FrameDecoder {
            x: 0.0,
            z: 0.0,
            frames: 0,
            feet: None,
            pin: None,
        }
    }
    /// The root's ground path from the feet instead of the velocity slots.
    pub fn root_from_feet(mut self, vocab: &Vocabulary) -> Result<FrameDecoder, LmError> {
        let sk = vocab.skeleton_def().ok_or_else(|| {
            LmError::invalid("model", "vocabulary.skeleton", vocab.skeleton.clone())
        })?;
        self.feet = Some(crate::motion::contact::FootLock::new(&sk));
        Ok(self)
    }
    /// The feet pinned where they touch the floor
    /// ([`crate::motion::foot_pin`]), after the root's path is set.
    pub fn pin_feet(mut self, vocab: &Vocabulary) -> Result<FrameDecoder, LmError> {
        let sk = vocab.skeleton_def().ok_or_else(|| {
            LmError::invalid("model", "vocabulary.skeleton", vocab.skeleton.clone())
        })?;
        let pin = crate::motion::foot_pin::FootPin::new(&sk, vocab.fps).ok_or_else(|| {
            LmError::invalid(
                "request",
                "feet",
                "pin: the model's skeleton has no legs to solve",
            )
        })?;
        self.pin = Some((pin, sk));
        Ok(self)
    }
    /// One frame: (rotations per joint, root translation).
    pub fn decode(
        &mut self,
        vocab: &Vocabulary,
        frame: &[u32],
    ) -> Result<(Vec<[f64; 3]>, [f64; 3]), LmError> {
        let one = vocab.decode_motion(frame, "generated")?;
        let carried = if self.frames > 0 {
            let (vx, vz) = vocab.decode_root_velocity(frame);
            [vx / vocab.fps, vz / vocab.fps]
        } else {
            [0.0, 0.0]
        };
        let mut lift = 0.0;
        match &mut self.feet {
            Some(lock) => {
                let pose = one.positions();
                [self.x, self.z] = lock.step(&pose, carried);
                lift = lock.ground_lift(&pose);
            }
            None => {
                self.x += carried[0];
                self.z += carried[1];
            }
        }
        self.frames += 1;
        let t = one.trans[0];
        let trans = [t[0] + self.x, t[1] + lift, t[2] + self.z];
        let mut rotations = one.frame_rotations(0).to_vec();
        if let Some((pin, sk)) = &mut self.pin {
            pin.step(sk, &mut rotations, trans);
        }
        Ok((rotations, trans))
    }
}

/// Class probabilities of a clip: windows of the model's length (half
/// overlapping, at most `max_windows` spread evenly), each read through the
/// class tokens at its end; probabilities averaged over windows. Returns,
/// per kind in the model's order, (value, probability) sorted by
/// probability.
pub fn classify(
    session: &LmSession,
    frame_tokens: &[u32],
    max_windows: usize,
) -> Result<Vec<(String, Vec<(String, f64)>)>, LmError> {
    let m = &session.manifest;
    let cfg = &m.config;
    let fl = cfg.frame_len;
    if cfg.classes.is_empty() {
        return Err(LmError::invalid(
            "model",
            "classes",
            "this model has no class heads",
        ));
    }
    let frames = frame_tokens.len() / fl;
    if frames == 0 {
        return Err(LmError::invalid(
            "request",
            "motion",
            "no whole frame to classify",
        ));
    }
    let w = cfg.max_frames.min(frames);
    let starts = classify_starts(frames, w, max_windows);
    let nk = cfg.classes.len();
    let mut acc: Vec<Vec<f64>> = cfg
        .classes
        .iter()
        .map(|(_, v)| vec![0.0; v.len()])
        .collect();
    for &s0 in &starts {
        let mut toks = vec![m.vocabulary.bos()];
        toks.extend_from_slice(&frame_tokens[s0 * fl..(s0 + w) * fl]);
        for (k, _) in &cfg.classes {
            toks.push(m.vocabulary.class_token(k)?);
        }
        let pos = cfg.positions(1, w * fl, nk);
        let (out, _) = session.step(&toks, &pos, Kv::empty(cfg))?;
        for (c, (_, values)) in cfg.classes.iter().enumerate() {
            let row = 1 + w * fl + c;
            let n = values.len();
            add_softmax(
                &mut acc[c],
                &out.class_logits[c][row * n..(row + 1) * n],
                1.0 / starts.len() as f64,
            );
        }
    }
    Ok(class_table(&cfg.classes, acc))
}
