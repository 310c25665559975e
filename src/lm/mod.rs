//! The motion language model as the server runs it (thesis 000 §4.5–4.7,
//! SPEC §5): the architecture settings and sequence layout shared with the
//! trainer, the manifest that travels beside the ONNX file, the tract
//! session with incremental decoding, sampling, generation with joint
//! prompts, and classification.
//!
//! A training or generation sequence is
//!
//! ```text
//! <bos> <KIND=VALUE>…  f0s0 f0s1 … f0s42(<sep>)  f1s0 …  [<cls:KIND>…]
//! └── prefix ──────┘  └──────────── frames (43 tokens each) ───┘ └ classes ┘
//! ```
//!
//! Positions are either absolute (the token's index) or the thesis's pair
//! (frame index, slot index) summed from two tables (§4.5.2, Fig. 4.8):
//! prefix tokens sit at frame 0 / slot 43, frame tokens at frame f+1 /
//! slot s, class tokens at frame 0 / slot 44. The functions here are the
//! only place that says so; the trainer and the server both call them.

pub mod best_of;
pub mod duet;
pub mod embed;
pub mod engine;
pub mod exemplars;
mod flips;
pub mod frame;
mod frame_draw;
pub mod frame_generator;
pub mod frame_runtime;
pub mod generate;
pub mod inbetween;
pub mod manifest;
pub mod matching;
pub mod model;
pub mod pace;
pub mod posture;
pub mod runtime;
pub mod sampling;
pub mod skate;
pub mod steer;
pub mod typical;

pub use generate::{classify, forced_frames, prompt_slots, FrameDecoder, Generator};
pub use manifest::Manifest;
pub use runtime::{Kv, LmSession};
pub use sampling::Sampling;

use serde::{Deserialize, Serialize};

/// How a token's position is embedded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PosScheme {
    /// One learned vector per sequence index.
    Absolute,
    /// Frame-index plus slot-index vectors, summed (thesis Fig. 4.8).
    FrameSlot,
}

/// What the model was trained to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Objective {
    /// Next-token prediction under a causal mask.
    Causal,
    /// 15 % of frame tokens replaced by `<mask>`, bidirectional attention.
    Masked,
}

/// The architecture and sequence layout of a model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelConfig {
    pub vocab_size: usize,
    pub d_model: usize,
    pub n_layers: usize,
    pub n_heads: usize,
    pub d_ff: usize,
    /// Frames in one context window.
    pub max_frames: usize,
    /// Tokens per frame (43 for the default vocabulary).
    pub frame_len: usize,
    /// Label kinds that may appear in the prefix, in prefix order.
    pub cond_kinds: Vec<String>,
    /// Label kind → class values, one linear head each (may be empty).
    pub classes: Vec<(String, Vec<String>)>,
    pub positions: PosScheme,
    pub objective: Objective,
    pub ln_eps: f64,
}

/// One token's position: `a` is the absolute index or the frame index,
/// `b` the slot index (0 under the absolute scheme).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pos {
    pub a: i64,
    pub b: i64,
}

impl ModelConfig {
    pub fn max_prefix(&self) -> usize {
        1 + self.cond_kinds.len()
    }
    /// The longest sequence the position tables cover.
    pub fn block(&self) -> usize {
        self.max_prefix() + self.max_frames * self.frame_len + self.classes.len()
    }
    pub fn d_head(&self) -> usize {
        self.d_model / self.n_heads
    }
    /// Rows of the first position table.
    pub fn table_a(&self) -> usize {
        match self.positions {
            PosScheme::Absolute => self.block(),
            PosScheme::FrameSlot => self.max_frames + 1,
        }
    }
    /// Rows of the slot table (0 under the absolute scheme).
    pub fn table_b(&self) -> usize {
        match self.positions {
            PosScheme::Absolute => 0,
            PosScheme::FrameSlot => self.frame_len + 2,
        }
    }
    /// The `i`-th prefix token.
    pub fn prefix_pos(&self, i: usize) -> Pos {
        match self.positions {
            PosScheme::Absolute => Pos { a: i as i64, b: 0 },
            PosScheme::FrameSlot => Pos {
                a: 0,
                b: self.frame_len as i64,
            },
        }
    }
    /// The `j`-th frame token after a prefix of `prefix_len`.
    pub fn frame_pos(&self, prefix_len: usize, j: usize) -> Pos {
        match self.positions {
            PosScheme::Absolute => Pos {
                a: (prefix_len + j) as i64,
                b: 0,
            },
            PosScheme::FrameSlot => Pos {
                a: (j / self.frame_len + 1) as i64,
                b: (j % self.frame_len) as i64,
            },
        }
    }
    /// The `c`-th class token after `n_frame_tokens` frame tokens.
    pub fn class_pos(&self, prefix_len: usize, n_frame_tokens: usize, c: usize) -> Pos {
        match self.positions {
            PosScheme::Absolute => Pos {
                a: (prefix_len + n_frame_tokens + c) as i64,
                b: 0,
            },
            PosScheme::FrameSlot => Pos {
                a: 0,
                b: self.frame_len as i64 + 1,
            },
        }
    }
    /// Positions of a whole sequence: `prefix_len` prefix tokens, then
    /// `n_frame_tokens`, then `n_class` class tokens.
    pub fn positions(&self, prefix_len: usize, n_frame_tokens: usize, n_class: usize) -> Vec<Pos> {
        let mut out = Vec::with_capacity(prefix_len + n_frame_tokens + n_class);
        out.extend((0..prefix_len).map(|i| self.prefix_pos(i)));
        out.extend((0..n_frame_tokens).map(|j| self.frame_pos(prefix_len, j)));
        out.extend((0..n_class).map(|c| self.class_pos(prefix_len, n_frame_tokens, c)));
        out
    }
    /// Checks that the sizes fit together.
    pub fn validate(&self, file: &str) -> Result<(), LmError> {
        let bad = |field: &str, reason: String| LmError::invalid(file, field, reason);
        check_heads(file, self.d_model, self.n_heads)?;
        if self.n_layers == 0 || self.d_ff == 0 || self.vocab_size == 0 {
            return Err(bad(
                "config",
                "n_layers, d_ff and vocab_size must be positive".into(),
            ));
        }
        if self.max_frames < 2 {
            return Err(bad(
                "config.max_frames",
                format!("{} (need at least 2)", self.max_frames),
            ));
        }
        Ok(())
    }
}

/// `d_model` splits into `n_heads` heads.
pub fn check_heads(file: &str, d_model: usize, n_heads: usize) -> Result<(), LmError> {
    if d_model == 0 || n_heads == 0 || d_model % n_heads != 0 {
        return Err(LmError::invalid(
            file,
            "config.n_heads",
            format!("d_model {d_model} is not a positive multiple of n_heads {n_heads}"),
        ));
    }
    Ok(())
}

/// Errors of loading and running a model: every one names the file or the
/// request field and the reason.
#[derive(Debug, thiserror::Error)]
pub enum LmError {
    #[error("{file}: field `{field}`: {reason}")]
    Invalid {
        file: String,
        field: String,
        reason: String,
    },
    #[error("{file}: {reason}")]
    Io { file: String, reason: String },
    #[error("model: {0}")]
    Runtime(String),
}

/// A JSON file a model folder may hold (`path`): None when absent, else
/// its parse, an unreadable file an `Io` error and a malformed one an
/// error naming `what` (returned with the path's display name, for the
/// caller's own field errors).
pub fn read_optional_json<T: serde::de::DeserializeOwned>(
    path: &std::path::Path,
    what: &str,
) -> Result<Option<(T, String)>, LmError> {
    if !path.exists() {
        return Ok(None);
    }
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| LmError::Io {
        file: name.clone(),
        reason: e.to_string(),
    })?;
    let v =
        serde_json::from_str(&text).map_err(|e| LmError::invalid(&name, what, e.to_string()))?;
    Ok(Some((v, name)))
}

impl LmError {
    pub fn invalid(
        file: impl Into<String>,
        field: impl Into<String>,
        reason: impl Into<String>,
    ) -> Self {
        LmError::Invalid {
            file: file.into(),
            field: field.into(),
            reason: reason.into(),
        }
    }
}

impl From<crate::motion::MotionError> for LmError {
    fn from(e: crate::motion::MotionError) -> Self {
        match e {
            crate::motion::MotionError::Invalid {
                file,
                field,
                reason,
            } => LmError::Invalid {
                file,
                field,
                reason,
            },
            other => LmError::Runtime(other.to_string()),
        }
    }
}

/// A full benchmark window: `<bos>` then `max_frames` frames of valid
/// tokens spread over the bins, with its positions. Shared by the runtime
/// benchmark and the trainer's, so both time the same input.
pub fn bench_window(
    cfg: &ModelConfig,
    vocab: &crate::tokenize::vocab::Vocabulary,
) -> (Vec<u32>, Vec<Pos>) {
    let mut toks = vec![vocab.bos()];
    let nf = cfg.max_frames * cfg.frame_len;
    for j in 0..nf {
        let r = vocab.allowed(j % cfg.frame_len);
        toks.push(if r.len() == 1 {
            r.start
        } else {
            r.start + ((j * 37) % r.len()) as u32
        });
    }
    (toks, cfg.positions(1, nf, 0))
}

/// Bits per frame from a mean loss in nats per token (SPEC §5:
/// tokens per frame × loss / ln 2).
pub fn bits_per_frame(loss_nats: f64, frame_len: usize) -> f64 {
    frame_len as f64 * loss_nats / std::f64::consts::LN_2
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(p: PosScheme) -> ModelConfig {
        ModelConfig {
            vocab_size: 400,
            d_model: 32,
            n_layers: 1,
            n_heads: 2,
            d_ff: 64,
            max_frames: 4,
            frame_len: 43,
            cond_kinds: vec!["genre".into(), "dancer".into()],
            classes: vec![("genre".into(), vec!["a".into(), "b".into()])],
            positions: p,
            objective: Objective::Causal,
            ln_eps: 1e-5,
        }
    }

    #[test]
    fn frame_slot_positions_follow_figure_4_8() {
        let c = cfg(PosScheme::FrameSlot);
        let p = c.positions(2, 86, 1);
        assert_eq!(p[0], Pos { a: 0, b: 43 });
        assert_eq!(p[2], Pos { a: 1, b: 0 });
        assert_eq!(p[2 + 42], Pos { a: 1, b: 42 });
        assert_eq!(p[2 + 43], Pos { a: 2, b: 0 });
        assert_eq!(p[88], Pos { a: 0, b: 44 });
        assert!(p
            .iter()
            .all(|q| (q.a as usize) < c.table_a() && (q.b as usize) < c.table_b()));
        assert_eq!(c.block(), 3 + 4 * 43 + 1);
    }

    #[test]
    fn absolute_positions_are_indices() {
        let c = cfg(PosScheme::Absolute);
        let p = c.positions(3, 4 * 43, 1);
        assert!(p
            .iter()
            .enumerate()
            .all(|(i, q)| q.a == i as i64 && q.b == 0));
        assert_eq!(p.len(), c.block());
    }

    #[test]
    fn bits_per_frame_is_tokens_times_loss_over_ln2() {
        assert!((bits_per_frame(std::f64::consts::LN_2, 43) - 43.0).abs() < 1e-12);
    }
}
