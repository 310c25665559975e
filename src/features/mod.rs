//! Spectral embeddings of motion windows (thesis 000 §3.4, SPEC §2). Pure.
//!
//! A motion becomes the canonical channel matrix ([`channels72`]): SMPL-24
//! local axis-angle, 72 channels, at 60 fps (non-SMPL skeletons are
//! retargeted onto the 13-joint subset, the other joints left at rest).
//! Windows of 128 frames (2.13 s) are cut every `hop` frames; each window is
//! held channel-major, `[72][128]`.
//!
//! - STFT: per channel, periodic Hann window of 16, hop 8, no padding:
//!   15 frames × 9 bins of |rfft| → 72 × 135 = 9,720 values.
//! - DCT: orthonormal DCT-II per channel, first 16 coefficients → 1,152.
//! - PCA: 16 components fitted on the per-channel 128-sample series of the
//!   indexed windows; each channel's series projected → 1,152.
//! - Pose: joint positions relative to the pelvis, heading removed, first 16
//!   DCT-II coefficients per coordinate → 624 ([`pose`]); the embedding
//!   that finds motion estimated from video and the mocap it shows.

pub mod interpolate;
pub mod lda;
pub mod pca;
pub mod pose;
pub mod project;
pub mod whiten;

use crate::motion::retarget::{retarget_to_smpl13, JointMap};
use crate::motion::{Motion, MotionError};
use rustdct::DctPlanner;
use rustfft::{num_complex::Complex, FftPlanner};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::Arc;

pub use pca::Pca;

/// Frames per window (at [`FEATURE_FPS`]).
pub const WINDOW: usize = 128;
/// The frame rate windows are cut at.
pub const FEATURE_FPS: f64 = 60.0;
/// Channels: 24 SMPL joints × 3 axis-angle components.
pub const CHANNELS: usize = 72;
/// Kept DCT / PCA coefficients per channel.
pub const COEFFS: usize = 16;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Embedding {
    Stft,
    Dct,
    Pca,
    Pose,
    /// What the frame model's class heads read in the window ([`crate::lm::embed`]);
    /// only where a frame model is loaded.
    Lm,
}

impl Embedding {
    /// The thesis's three spectral embeddings of the rotation channels.
    pub const ALL: [Embedding; 3] = [Embedding::Stft, Embedding::Dct, Embedding::Pca];
    /// Every embedding the store keeps for a window.
    pub const STORED: [Embedding; 4] = [
        Embedding::Stft,
        Embedding::Dct,
        Embedding::Pca,
        Embedding::Pose,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Embedding::Stft => "stft",
            Embedding::Dct => "dct",
            Embedding::Pca => "pca",
            Embedding::Pose => "pose",
            Embedding::Lm => "lm",
        }
    }
    pub fn parse(s: &str) -> Option<Embedding> {
        match s.to_ascii_lowercase().as_str() {
            "stft" => Some(Embedding::Stft),
            "dct" => Some(Embedding::Dct),
            "pca" => Some(Embedding::Pca),
            "pose" => Some(Embedding::Pose),
            "lm" => Some(Embedding::Lm),
            _ => None,
        }
    }
}

/// STFT settings (SPEC §2 defaults: window 16, hop 8).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StftParams {
    pub win: usize,
    pub hop: usize,
}

impl Default for StftParams {
    fn default() -> Self {
        StftParams { win: 16, hop: 8 }
    }
}

impl StftParams {
    pub fn frames(&self) -> usize {
        1 + (WINDOW - self.win) / self.hop
    }
    pub fn bins(&self) -> usize {
        self.win / 2 + 1
    }
    pub fn dim(&self) -> usize {
        CHANNELS * self.frames() * self.bins()
    }
    pub fn validate(&self) -> Result<(), MotionError> {
        if self.win < 2 || self.win > WINDOW || self.hop == 0 || self.hop > self.win {
            return Err(MotionError::invalid(
                "stft",
                "win/hop",
                format!(
                    "window {} and hop {} must satisfy 2 <= win <= {WINDOW}, 1 <= hop <= win",
                    self.win, self.hop
                ),
            ));
        }
        Ok(())
    }
}

/// Index `i` into a sequence of `n` (> 0) items with half-sample symmetric
/// edges (`d c b a | a b c d | d c b a`, scipy's "reflect" mode).
pub fn reflect_index(i: i64, n: usize) -> usize {
    let n = n as i64;
    let mut i = i;
    while i < 0 || i >= n {
        i = if i < 0 { -i - 1 } else { 2 * n - i - 1 };
    }
    i as usize
}

/// A motion as SMPL-24 at 60 fps: SMPL-13 is expanded (dropped joints at
/// rest), other skeletons are retargeted (built-in joint map) onto the
/// 13-joint subset first.
pub fn smpl24_at_60(m: &Motion) -> Result<Motion, MotionError> {
    let smpl = match m.skeleton.kind.as_str() {
        "smpl24" => m.clone(),
        _ => as_smpl13(m)?.smpl13_to_smpl24()?,
    };
    smpl.resample(FEATURE_FPS)
}

/// A motion on the 13-joint SMPL subset: SMPL-24 is reduced (dropped chains
/// composed into the kept joints), other skeletons are retargeted with the
/// built-in joint map.
pub fn as_smpl13(m: &Motion) -> Result<Motion, MotionError> {
    match m.skeleton.kind.as_str() {
        "smpl13" => Ok(m.clone()),
        "smpl24" => m.to_smpl13(),
        _ => {
            let map =
                JointMap::resolve(&m.skeleton, &BTreeMap::new()).map_err(|e| e.in_file(&m.name))?;
            retarget_to_smpl13(m, &map)
        }
    }
}

/// The rows of an SMPL-24 motion's rotations as `[frames][72]` f32.
pub fn rows72(smpl: &Motion) -> Vec<[f32; CHANNELS]> {
    (0..smpl.frames())
        .map(|f| {
            let mut row = [0f32; CHANNELS];
            for (j, r) in smpl.frame_rotations(f).iter().enumerate() {
                row[3 * j] = r[0] as f32;
                row[3 * j + 1] = r[1] as f32;
                row[3 * j + 2] = r[2] as f32;
            }
            row
        })
        .collect()
}

/// The canonical channel matrix of a motion: `[frames][72]` f32 at 60 fps,
/// SMPL-24 local axis-angle (see [`smpl24_at_60`]).
pub fn channels72(m: &Motion) -> Result<Vec<[f32; CHANNELS]>, MotionError> {
    Ok(rows72(&smpl24_at_60(m)?))
}

/// Window start frames for `frames` frames: `0, hop, 2·hop, …` while a whole
/// window fits.
pub fn window_starts(frames: usize, hop: usize) -> Vec<usize> {
    if frames < WINDOW || hop == 0 {
        return Vec::new();
    }
    (0..=(frames - WINDOW) / hop).map(|i| i * hop).collect()
}

/// One window, channel-major `[72][128]`.
pub fn window(ch: &[[f32; CHANNELS]], start: usize) -> Vec<f32> {
    let mut w = vec![0f32; CHANNELS * WINDOW];
    for t in 0..WINDOW {
        let row = &ch[start + t];
        for c in 0..CHANNELS {
            w[c * WINDOW + t] = row[c];
        }
    }
    w
}

/// Reusable FFT/DCT plans; cheap to clone and share across threads.
#[derive(Clone)]
pub struct Extractor {
    pub stft: StftParams,
    fft: Arc<dyn rustfft::Fft<f32>>,
    hann: Vec<f32>,
    dct: Arc<dyn rustdct::TransformType2And3<f32>>,
    /// The first 16 orthonormal DCT-II functions as one blocked projection.
    dct16: Arc<project::Projection>,
    /// The same functions, `[16][128]`.
    dct_rows: Arc<Vec<f32>>,
}

impl Extractor {
    pub fn new(stft: StftParams) -> Result<Self, MotionError> {
        stft.validate()?;
        let fft = FftPlanner::new().plan_fft_forward(stft.win);
        // Periodic Hann (scipy.signal.get_window('hann', N)).
        let hann = (0..stft.win)
            .map(|n| {
                (0.5 - 0.5 * (2.0 * std::f64::consts::PI * n as f64 / stft.win as f64).cos()) as f32
            })
            .collect();
        let dct = DctPlanner::new().plan_dct2(WINDOW);
        // Orthonormal DCT-II: X_k = s_k Σ_t x_t cos(π k (2t + 1) / 2N).
        let n = WINDOW as f64;
        let rows: Vec<f32> = (0..COEFFS)
            .flat_map(|k| {
                let s = if k == 0 {
                    (1.0 / n).sqrt()
                } else {
                    (2.0 / n).sqrt()
                };
                (0..WINDOW).map(move |t| {
                    (s * (std::f64::consts::PI * k as f64 * (2 * t + 1) as f64 / (2.0 * n)).cos())
                        as f32
                })
            })
            .collect();
        Ok(Extractor {
            stft,
            fft,
            hann,
            dct,
            dct16: Arc::new(project::Projection::new(&rows, None)),
            dct_rows: Arc::new(rows),
        })
    }

    pub fn dim(&self, e: Embedding) -> usize {
        match e {
            Embedding::Stft => self.stft.dim(),
            Embedding::Dct | Embedding::Pca => CHANNELS * COEFFS,
            Embedding::Pose => pose::POSE_DIM,
            // The model's width; the embedder says it.
            Embedding::Lm => 0,
        }
    }

    /// STFT magnitudes, flattened `[channel][frame][bin]`.
    pub fn stft(&self, win: &[f32]) -> Vec<f32> {
        let (n, hop) = (self.stft.win, self.stft.hop);
        let (frames, bins) = (self.stft.frames(), self.stft.bins());
        let mut out = Vec::with_capacity(CHANNELS * frames * bins);
        let mut buf = vec![Complex::new(0f32, 0f32); n];
        for c in 0..CHANNELS {
            let x = &win[c * WINDOW..(c + 1) * WINDOW];
            for f in 0..frames {
                for (k, b) in buf.iter_mut().enumerate() {
                    *b = Complex::new(x[f * hop + k] * self.hann[k], 0.0);
                }
                self.fft.process(&mut buf);
                // |z| as sqrt(re² + im²): libm's hypotf guards against
                // overflow that 16 bounded samples cannot reach, at 3 % of a
                // query's time under load.
                out.extend(buf[..bins].iter().map(|z| z.norm_sqr().sqrt()));
            }
        }
        out
    }

    /// Orthonormal DCT-II of every channel, all 128 coefficients, `[72][128]`.
    pub fn dct_full(&self, win: &[f32]) -> Vec<f32> {
        let mut out = win.to_vec();
        let s0 = (1.0 / WINDOW as f32).sqrt();
        let sk = (2.0 / WINDOW as f32).sqrt();
        for c in 0..CHANNELS {
            let ch = &mut out[c * WINDOW..(c + 1) * WINDOW];
            self.dct.process_dct2(ch);
            ch[0] *= s0;
            for v in ch[1..].iter_mut() {
                *v *= sk;
            }
        }
        out
    }

    /// First 16 orthonormal DCT-II coefficients per channel, `[72][16]`
    /// (one blocked product with the 16 basis functions, not a full DCT).
    pub fn dct(&self, win: &[f32]) -> Vec<f32> {
        self.dct16.apply(win)
    }

    /// The pose embedding ([`pose`]).
    pub fn pose(&self, win: &[f32]) -> Vec<f32> {
        pose::pose_embedding(win, &self.dct_rows)
    }

    /// The embedding of one window. PCA needs a fitted model.
    pub fn embed(
        &self,
        e: Embedding,
        win: &[f32],
        pca: Option<&Pca>,
    ) -> Result<Vec<f32>, MotionError> {
        match e {
            Embedding::Stft => Ok(self.stft(win)),
            Embedding::Dct => Ok(self.dct(win)),
            Embedding::Pose => Ok(self.pose(win)),
            Embedding::Pca => {
                let p = pca.ok_or_else(|| {
                    MotionError::invalid(
                        "pca",
                        "model",
                        "no PCA model fitted yet (ingest motions first)",
                    )
                })?;
                Ok(p.project_window(win))
            }
            Embedding::Lm => Err(MotionError::invalid(
                "lm",
                "model",
                "the lm embedding is the model's: it needs a frame model loaded (--model)",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dct_of_a_constant_is_its_dc_term() {
        let ex = Extractor::new(StftParams::default()).unwrap();
        let w = vec![0.5f32; CHANNELS * WINDOW];
        let d = ex.dct(&w);
        // Orthonormal: X0 = sqrt(N) * 0.5, the rest zero.
        assert!((d[0] - 0.5 * (WINDOW as f32).sqrt()).abs() < 1e-4);
        assert!(d[1..COEFFS].iter().all(|v| v.abs() < 1e-4));
    }

    #[test]
    fn stft_of_a_sine_peaks_at_its_bin() {
        // A sine with 2 cycles per 16 samples lands in bin 2 of every frame.
        let ex = Extractor::new(StftParams::default()).unwrap();
        let mut w = vec![0f32; CHANNELS * WINDOW];
        for t in 0..WINDOW {
            w[t] = (2.0 * std::f32::consts::PI * 2.0 * t as f32 / 16.0).sin();
        }
        let s = ex.stft(&w);
        assert_eq!(s.len(), StftParams::default().dim());
        for f in 0..15 {
            let bins = &s[f * 9..(f + 1) * 9];
            let arg = bins
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .unwrap()
                .0;
            assert_eq!(arg, 2);
            // Hann-windowed sine of amplitude 1: peak magnitude N/4 = 4.
            assert!((bins[2] - 4.0).abs() < 1e-4, "{}", bins[2]);
        }
    }

    #[test]
    fn windows_cover_whole_windows_only() {
        assert_eq!(window_starts(127, 32), Vec::<usize>::new());
        assert_eq!(window_starts(128, 32), vec![0]);
        assert_eq!(window_starts(200, 32), vec![0, 32, 64]);
    }
}
