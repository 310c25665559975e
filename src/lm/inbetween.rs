//! The learned in-betweener (thesis 001 §3.5.3, the *Motion* and *Genre*
//! variants; SPEC §6): a small bidirectional transformer that looks at a
//! window of interpolated keyframes (SLERP, the thesis's, or a Catmull-Rom
//! spline: the config's [`Base`]) and predicts what the interpolation got
//! wrong — the residual to the real motion — for every in-between frame.
//!
//! Frames are SMPL-24 at 60 fps. A frame's pose is each joint's rotation
//! in the continuous 6D form (the first two columns of its matrix) and the
//! root translation: [`POSE_DIM`] = 24 · 6 + 3 numbers. The model's input
//! per frame is the base pose (root x, z made relative to the window's
//! first frame), the frame's phase between its two keyframes, the length
//! of that segment in seconds, and the conditioning one-hot (a label kind
//! such as `genre`; all zeros when the label is absent or unknown). The
//! output is the residual pose. Keyframes themselves are never changed
//! (their residual is masked to 0), and windows overlap by half with Hann
//! weights, so a long clip is rebuilt without seams.
//!
//! The trainer (`choreo-train inbetween`) fits and exports it; the server
//! loads it with tract through [`Inbetweener`].

use super::engine::{Dim, Engine, Graph, GraphSpec, In, Outputs};
use super::manifest::{read_manifest, read_onnx_checked, DataInfo};
use super::LmError;
use crate::motion::rotation::{axis_angle_to_mat, mat_to_6d, mat_to_axis_angle, sixd_to_mat};
use crate::motion::{Labels, Motion, MotionError};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

/// Joints of the pose (SMPL-24).
pub const JOINTS: usize = 24;
/// Numbers per pose: 6D per joint, then the root translation.
pub const POSE_DIM: usize = JOINTS * 6 + 3;
/// The manifest's `kind`.
pub const KIND: &str = "inbetweener";
pub const FORMAT: u32 = 1;
/// Windows per graph run when rebuilding a clip.
pub const BATCH: usize = 32;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InbetweenConfig {
    /// Frames per window (60 fps); windows overlap by half.
    pub window: usize,
    pub d_model: usize,
    pub n_layers: usize,
    pub n_heads: usize,
    pub d_ff: usize,
    pub ln_eps: f64,
    /// The label kind conditioned on and its values (one-hot), or none
    /// (the *Motion* variant).
    pub condition: Option<(String, Vec<String>)>,
    /// The in-betweens the model starts from and corrects (models written
    /// before this field: SLERP).
    #[serde(default)]
    pub base: Base,
}

/// The interpolation a model's residual is added to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Base {
    /// SLERP of every joint, the root lerped (thesis 001 §3.5.3).
    #[default]
    Slerp,
    /// Catmull-Rom through the keyframes ([`crate::keyframes::inbetween::catmull_rom`]).
    CatmullRom,
}

impl Base {
    /// The base in-betweens of a clip from its keyframes.
    pub fn rebuild(self, m: &Motion, keys: &[usize]) -> Result<Motion, MotionError> {
        match self {
            Base::Slerp => crate::keyframes::inbetween::slerp(m, keys),
            Base::CatmullRom => crate::keyframes::inbetween::catmull_rom(m, keys),
        }
    }
}

impl InbetweenConfig {
    pub fn cond_dim(&self) -> usize {
        self.condition.as_ref().map_or(0, |c| c.1.len())
    }
    /// Numbers per input frame.
    pub fn in_dim(&self) -> usize {
        POSE_DIM + 2 + self.cond_dim()
    }
    pub fn d_head(&self) -> usize {
        self.d_model / self.n_heads.max(1)
    }
    pub fn validate(&self, file: &str) -> Result<(), LmError> {
        let bad = |field: &str, reason: String| LmError::invalid(file, field, reason);
        super::check_heads(file, self.d_model, self.n_heads)?;
        if self.n_layers == 0 || self.d_ff == 0 {
            return Err(bad("config", "n_layers and d_ff must be positive".into()));
        }
        if self.window < 4 || self.window % 2 != 0 {
            return Err(bad(
                "config.window",
                format!("{} (an even number of frames, at least 4)", self.window),
            ));
        }
        Ok(())
    }

    /// The conditioning one-hot for a motion's labels.
    pub fn condition_vector(&self, labels: &Labels) -> Vec<f32> {
        let Some((kind, values)) = &self.condition else {
            return Vec::new();
        };
        let mut v = vec![0f32; values.len()];
        if let Some(i) = labels
            .get(kind)
            .and_then(|l| values.iter().position(|x| x == l))
        {
            v[i] = 1.0;
        }
        v
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InbetweenManifest {
    pub format: u32,
    /// Always [`KIND`].
    pub kind: String,
    pub config: InbetweenConfig,
    pub onnx: String,
    pub onnx_sha256: String,
    pub data: DataInfo,
    /// Held-out figures (MSE against SLERP and Bézier …).
    pub metrics: BTreeMap<String, f64>,
    pub training: serde_json::Value,
}

/// Every frame's pose ([`POSE_DIM`] numbers) of a SMPL-24 motion.
pub fn poses(m: &Motion) -> Result<Vec<[f64; POSE_DIM]>, MotionError> {
    if m.joints() != JOINTS {
        return Err(MotionError::invalid(
            &m.name,
            "skeleton",
            format!("{} joints; the in-betweener works on SMPL-24", m.joints()),
        ));
    }
    Ok((0..m.frames())
        .map(|t| {
            let mut p = [0f64; POSE_DIM];
            for (j, aa) in m.frame_rotations(t).iter().enumerate() {
                p[j * 6..j * 6 + 6].copy_from_slice(&mat_to_6d(&axis_angle_to_mat(*aa)));
            }
            p[JOINTS * 6..].copy_from_slice(&m.trans[t]);
            p
        })
        .collect())
}

/// Per frame: (phase between its keyframes in [0, 1], segment length in
/// seconds at 60 fps). Keyframes have phase 0 (or 1 for the last).
pub fn phases(keys: &[usize], frames: usize) -> Vec<(f32, f32)> {
    let mut out = vec![(0f32, 0f32); frames];
    for w in keys.windows(2) {
        let (a, b) = (w[0], w[1].min(frames.saturating_sub(1)));
        let len = (b - a).max(1) as f32;
        for (t, o) in out.iter_mut().enumerate().take(b + 1).skip(a) {
            *o = ((t - a) as f32 / len, len / 60.0);
        }
    }
    out
}

/// Whether a frame is an in-between (not a keyframe).
pub fn inbetween_mask(keys: &[usize], frames: usize) -> Vec<bool> {
    let mut m = vec![true; frames];
    for &k in keys {
        if k < frames {
            m[k] = false;
        }
    }
    m
}

/// Window starts covering `frames` with hop `window / 2`.
pub fn window_starts(frames: usize, window: usize) -> Vec<usize> {
    let hop = (window / 2).max(1);
    let mut s = vec![0];
    while s.last().unwrap() + window < frames {
        s.push(s.last().unwrap() + hop);
    }
    s
}

/// The model input of one window (`window × in_dim`, frame-major); frames
/// past the end repeat the last frame.
pub fn window_input(
    cfg: &InbetweenConfig,
    base: &[[f64; POSE_DIM]],
    phase: &[(f32, f32)],
    cond: &[f32],
    start: usize,
) -> Vec<f32> {
    let n = base.len();
    let d = cfg.in_dim();
    let mut x = Vec::with_capacity(cfg.window * d);
    let origin = base[start.min(n - 1)];
    for i in 0..cfg.window {
        let t = (start + i).min(n - 1);
        let p = &base[t];
        x.extend(p[..JOINTS * 6].iter().map(|&v| v as f32));
        let r = JOINTS * 6;
        x.push((p[r] - origin[r]) as f32);
        x.push(p[r + 1] as f32);
        x.push((p[r + 2] - origin[r + 2]) as f32);
        x.push(phase[t].0);
        x.push(phase[t].1);
        x.extend_from_slice(cond);
    }
    x
}

/// Hann weight of frame `i` of a window (never exactly 0, so a clip
/// covered by one window still gets its residual).
fn weight(i: usize, window: usize) -> f64 {
    let s = (std::f64::consts::PI * (i as f64 + 0.5) / window as f64).sin();
    s * s
}

/// The rebuilt motion: `base` plus the overlap-added residuals of the
/// windows at [`window_starts`], on in-between frames only.
pub fn apply_residuals(
    base: &Motion,
    base_poses: &[[f64; POSE_DIM]],
    keys: &[usize],
    window: usize,
    residuals: &[Vec<f32>],
) -> Motion {
    let n = base_poses.len();
    let mut acc = vec![[0f64; POSE_DIM]; n];
    let mut wsum = vec![0f64; n];
    for (start, r) in window_starts(n, window).into_iter().zip(residuals) {
        for i in 0..window {
            let t = start + i;
            if t >= n {
                break;
            }
            let w = weight(i, window);
            for (a, &v) in acc[t].iter_mut().zip(&r[i * POSE_DIM..(i + 1) * POSE_DIM]) {
                *a += w * v as f64;
            }
            wsum[t] += w;
        }
    }
    let mask = inbetween_mask(keys, n);
    let mut rots = base.rotations.clone();
    let mut trans = base.trans.clone();
    for t in 0..n {
        if !mask[t] || wsum[t] == 0.0 {
            continue;
        }
        let p: Vec<f64> = base_poses[t]
            .iter()
            .zip(&acc[t])
            .map(|(b, a)| b + a / wsum[t])
            .collect();
        for j in 0..JOINTS {
            let six: [f64; 6] = p[j * 6..j * 6 + 6].try_into().expect("6 numbers");
            rots[t * JOINTS + j] = mat_to_axis_angle(&sixd_to_mat(&six));
        }
        trans[t] = [p[JOINTS * 6], p[JOINTS * 6 + 1], p[JOINTS * 6 + 2]];
    }
    base.with_data(trans, rots)
}

/// An exported in-betweener on the model runtime (tract or ort).
pub struct Inbetweener {
    pub manifest: InbetweenManifest,
    /// The ONNX file it was loaded from.
    pub onnx_path: std::path::PathBuf,
    graph: Arc<dyn Graph>,
}

impl std::fmt::Debug for Inbetweener {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Inbetweener")
            .field("config", &self.manifest.config)
            .finish()
    }
}

impl Inbetweener {
    /// Loads a model folder (or its manifest), checking the ONNX file's
    /// hash and that the graph takes `x [B, window, in_dim]`.
    pub fn load(path: &Path) -> Result<Inbetweener, LmError> {
        Inbetweener::load_with(path, &Engine::tract())
    }

    /// Loads it on `engine`'s runtime.
    pub fn load_with(path: &Path, engine: &Engine) -> Result<Inbetweener, LmError> {
        let (file, name, m): (_, _, InbetweenManifest) = read_manifest(path)?;
        if m.format != FORMAT || m.kind != KIND {
            return Err(LmError::invalid(
                &name,
                "kind",
                format!(
                    "{} format {} (this build reads {KIND} format {FORMAT})",
                    m.kind, m.format
                ),
            ));
        }
        m.config.validate(&name)?;
        let (onnx_path, bytes) = read_onnx_checked(&file, &name, &m.onnx, &m.onnx_sha256)?;
        let cfg = &m.config;
        let graph = engine.load(
            &bytes,
            &GraphSpec {
                inputs: &["x".to_string()],
                outputs: 1,
                file: &onnx_path.display().to_string(),
                f32_shapes: &[vec![
                    Dim::Sym("B"),
                    Dim::N(cfg.window),
                    Dim::N(cfg.in_dim()),
                ]],
                batch: None,
            },
        )?;
        Ok(Inbetweener {
            manifest: m,
            onnx_path,
            graph,
        })
    }

    pub fn config(&self) -> &InbetweenConfig {
        &self.manifest.config
    }

    /// The residual of one window (`window × POSE_DIM`).
    pub fn run_window(&self, x: &[f32]) -> Result<Vec<f32>, LmError> {
        Ok(self.run_windows(&[x.to_vec()])?.remove(0))
    }

    /// The residuals of many windows, [`BATCH`] windows to a graph run.
    pub fn run_windows(&self, xs: &[Vec<f32>]) -> Result<Vec<Vec<f32>>, LmError> {
        let cfg = self.config();
        let (wi, wo) = (cfg.window * cfg.in_dim(), cfg.window * POSE_DIM);
        let mut state = self.graph.spawn()?;
        let mut res = Outputs::default();
        let mut out = Vec::with_capacity(xs.len());
        for chunk in xs.chunks(BATCH) {
            if let Some(x) = chunk.iter().find(|x| x.len() != wi) {
                return Err(LmError::Runtime(format!(
                    "a window of {} numbers, not {} × {}",
                    x.len(),
                    cfg.window,
                    cfg.in_dim()
                )));
            }
            let flat: Vec<f32> = chunk.concat();
            let shape = [chunk.len(), cfg.window, cfg.in_dim()];
            state.run(&[In::F32(&shape, &flat)], None, &mut res)?;
            let v = res.data(0);
            if v.len() != chunk.len() * wo {
                return Err(LmError::Runtime(format!(
                    "the graph returned {} numbers, not {} × {} × {POSE_DIM}",
                    v.len(),
                    chunk.len(),
                    cfg.window
                )));
            }
            out.extend(v.chunks(wo).map(<[f32]>::to_vec));
        }
        Ok(out)
    }

    /// Rebuild the in-betweens of a SMPL-24, 60 fps motion from its
    /// keyframes: the model's base (SLERP or Catmull-Rom), then its residual.
    pub fn rebuild(&self, m: &Motion, keys: &[usize]) -> Result<Motion, MotionError> {
        let cfg = self.config();
        let base = cfg.base.rebuild(m, keys)?;
        let base_poses = poses(&base)?;
        let phase = phases(keys, m.frames());
        let cond = cfg.condition_vector(&m.labels);
        let inputs: Vec<Vec<f32>> = window_starts(m.frames(), cfg.window)
            .into_iter()
            .map(|s| window_input(cfg, &base_poses, &phase, &cond, s))
            .collect();
        let residuals = self
            .run_windows(&inputs)
            .map_err(|e| MotionError::invalid(&m.name, "inbetweener", e.to_string()))?;
        Ok(apply_residuals(
            &base,
            &base_poses,
            keys,
            cfg.window,
            &residuals,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_cover_every_frame_and_weights_sum_positive() {
        for (n, w) in [(10, 64), (64, 64), (65, 64), (300, 64)] {
            let s = window_starts(n, w);
            assert_eq!(s[0], 0);
            assert!(s.last().unwrap() + w >= n, "{n} {w}");
        }
    }

    #[test]
    fn zero_residual_gives_back_the_base_and_poses_round_trip() {
        let m = crate::motion::clip::tests::sine_clip(150, 60.0);
        let keys = vec![0, 40, 90, 149];
        let base = crate::keyframes::inbetween::slerp(&m, &keys).unwrap();
        let bp = poses(&base).unwrap();
        let zeros: Vec<Vec<f32>> = window_starts(150, 64)
            .iter()
            .map(|_| vec![0f32; 64 * POSE_DIM])
            .collect();
        let back = apply_residuals(&base, &bp, &keys, 64, &zeros);
        for (a, b) in back.rotations.iter().zip(&base.rotations) {
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() < 1e-9, "{a:?} {b:?}");
            }
        }
        let ph = phases(&keys, 150);
        assert_eq!(ph[40], (0.0, 50.0 / 60.0));
        assert_eq!(ph[65].0, 0.5);
        assert_eq!(ph[149].0, 1.0);
    }

    #[test]
    fn the_residual_moves_inbetweens_only() {
        let m = crate::motion::clip::tests::sine_clip(100, 60.0);
        let keys = vec![0, 50, 99];
        let base = crate::keyframes::inbetween::slerp(&m, &keys).unwrap();
        let bp = poses(&base).unwrap();
        let ones: Vec<Vec<f32>> = window_starts(100, 64)
            .iter()
            .map(|_| {
                let mut r = vec![0f32; 64 * POSE_DIM];
                for i in 0..64 {
                    r[i * POSE_DIM + JOINTS * 6] = 0.1; // root x + 10 cm
                }
                r
            })
            .collect();
        let back = apply_residuals(&base, &bp, &keys, 64, &ones);
        for t in 0..100 {
            let dx = back.trans[t][0] - base.trans[t][0];
            let want = if keys.contains(&t) { 0.0 } else { 0.1 };
            assert!((dx - want).abs() < 1e-6, "frame {t}: {dx}");
        }
    }
}
