//! The model's reading of a window as a search embedding (`lm`): a window
//! of motion is tokenized on its own (SMPL-13 at the model's frame rate),
//! run through the frame model's global transformer with no labels, and
//! described by what the model's class heads make of it: per label kind,
//! the square roots of the tempered class probabilities
//! ([`FrameSession::classify`], the mean of each step's logits), all kinds
//! concatenated. Each kind's block has unit length, so every kind weighs
//! the same in a cosine, and the dot product of two blocks is their
//! Bhattacharyya coefficient: windows are near when the model would label
//! them alike, with its doubt included.
//!
//! The pooled states alone ([`FrameSession::pooled_states`], the first
//! version of `lm`) were measured too and lost to the spectral embeddings:
//! a model trained to predict the next frame encodes what the body does
//! now, which many performers share (docs/RESULTS.md, "The frame model's reading as
//! a search embedding").
//!
//! It reads the same window as the spectral embeddings: 128 frames of the
//! 72 SMPL-24 rotation channels at 60 fps ([`crate::features::window`]),
//! with the root held in place. So it describes how the body moves, not
//! where it travels (the same as STFT / DCT / PCA, and the only choice for
//! data with no root trajectory such as AIST++-VRM); a stored window is
//! embedded from the stored channels and a query window the same way,
//! whichever motion it came from.

use super::frame_runtime::FrameSession;
use super::model::MotionModel;
use super::LmError;
use crate::features::{CHANNELS, FEATURE_FPS, WINDOW};
use crate::motion::{Labels, Motion, Skeleton};
use std::sync::Arc;

/// Per kind, the square roots of the softmax of its logits (the softmax
/// `classify` answers with), concatenated.
fn hellinger(logits: &[Vec<f32>]) -> Vec<f32> {
    let mut out = Vec::with_capacity(logits.iter().map(Vec::len).sum());
    for l in logits {
        let mut p = vec![0f64; l.len()];
        super::generate::add_softmax(&mut p, l, 1.0);
        out.extend(p.iter().map(|x| x.sqrt() as f32));
    }
    out
}

/// A frame model ready to embed windows; cheap to clone.
#[derive(Clone)]
pub struct LmEmbedder {
    session: Arc<FrameSession>,
    /// The model's identity and the pooling's version, stored with the
    /// vectors so that a changed model (or pooling) re-embeds the archive.
    fingerprint: String,
}

impl LmEmbedder {
    /// The embedder of a loaded model; only the frame model has states to
    /// pool (the flat GPT's are per token).
    pub fn new(model: &MotionModel) -> Result<LmEmbedder, LmError> {
        match model {
            MotionModel::Frame(s) => Ok(LmEmbedder {
                session: s.clone(),
                fingerprint: format!("lm2-{}", s.manifest.global_sha256),
            }),
            MotionModel::Flat(_) => Err(LmError::invalid(
                "model",
                "kind",
                "the lm embedding needs a motion-frame-lm model; this one is motion-lm",
            )),
        }
    }

    pub fn fingerprint(&self) -> &str {
        &self.fingerprint
    }

    /// Dimensions of a vector: one per class of every label kind.
    pub fn dim(&self) -> usize {
        self.session
            .config()
            .classes
            .iter()
            .map(|(_, v)| v.len())
            .sum()
    }

    /// The `lm` vector of one window, channel-major `[72][128]`.
    pub fn window(&self, win: &[f32]) -> Result<Vec<f32>, LmError> {
        if win.len() != CHANNELS * WINDOW {
            return Err(LmError::invalid(
                "lm",
                "window",
                format!("{} values, a window has {}", win.len(), CHANNELS * WINDOW),
            ));
        }
        let rotations = (0..WINDOW)
            .flat_map(|t| {
                (0..CHANNELS / 3).map(move |j| {
                    let c = |k: usize| win[(3 * j + k) * WINDOW + t] as f64;
                    [c(0), c(1), c(2)]
                })
            })
            .collect();
        let m = Motion::new(
            "window",
            FEATURE_FPS,
            Skeleton::smpl24(),
            vec![[0.0; 3]; WINDOW],
            rotations,
            Labels::new(),
        )?;
        let vocab = &self.session.manifest.vocabulary;
        let tokens = vocab.encode_motion(&vocab.prepare(&m)?)?;
        let slots = self.session.config().slots;
        let values: Vec<u32> = tokens
            .chunks_exact(vocab.frame_len())
            .flat_map(|f| f[..slots].iter().copied())
            .collect();
        Ok(hellinger(&self.session.classify(&values)?))
    }

    /// [`LmEmbedder::window`] of many windows, split across the cores.
    pub fn many(&self, windows: &[Vec<f32>]) -> Result<Vec<Vec<f32>>, LmError> {
        let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
        let chunk = windows.len().div_ceil(threads).max(1);
        std::thread::scope(|s| {
            let parts: Vec<_> = windows
                .chunks(chunk)
                .map(|c| {
                    s.spawn(move || {
                        c.iter()
                            .map(|w| self.window(w))
                            .collect::<Result<Vec<_>, _>>()
                    })
                })
                .collect();
            let mut out = Vec::with_capacity(windows.len());
            for p in parts {
                out.extend(
                    p.join()
                        .map_err(|_| LmError::Runtime("an lm worker panicked".into()))??,
                );
            }
            Ok(out)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::hellinger;

    #[test]
    fn each_kind_is_a_unit_block_of_root_probabilities() {
        let v = hellinger(&[vec![0.0, (3f32).ln()], vec![1.0, 1.0, 1.0, 1.0]]);
        let want = [0.5, 0.75f32.sqrt(), 0.5, 0.5, 0.5, 0.5];
        for (a, b) in v.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{v:?}");
        }
        // Large logits do not overflow.
        let v = hellinger(&[vec![1e4, 0.0]]);
        assert!((v[0] - 1.0).abs() < 1e-6 && v[1] == 0.0);
    }
}
