//! Keypoints made from an SMPL take, degraded the way video estimators
//! degrade them: the test data of the footage readers and evaluation.

use super::*;
use crate::motion::clip::Motion;
use crate::motion::rotation::*;
use crate::motion::MotionError;
use rand::{Rng, SeedableRng};
use serde::Serialize;

/// How [`synthesize`] degrades clean keypoints, the way video estimators do.
#[derive(Clone, Debug, Serialize)]
pub struct SynthOptions {
    pub layout: Layout,
    /// Frame rate of the output (video rates: 30, 25, 24).
    pub fps: f64,
    /// Gaussian noise on every coordinate, metres (σ).
    pub noise_m: f64,
    /// Share of (frame, keypoint) pairs thrown off by `jitter_m`.
    pub jitter_share: f64,
    pub jitter_m: f64,
    /// Share of frames dropped (no detection: NaN), in runs of 2–12 frames.
    pub drop_share: f64,
    /// Share of frames in low-confidence spells (runs of 5–20 frames, 3×
    /// noise, confidence 0.1–0.4).
    pub low_conf_share: f64,
    /// Camera heading about the vertical, degrees (0: the mocap world's
    /// axes are the camera's, up to the up axis).
    pub yaw_deg: f64,
    /// File units per metre (1000 writes millimetres).
    pub units_per_metre: f64,
    pub seed: u64,
}

impl SynthOptions {
    /// Clean keypoints: no noise, no drops, full confidence.
    pub fn clean(layout: Layout, fps: f64) -> Self {
        SynthOptions {
            layout,
            fps,
            noise_m: 0.0,
            jitter_share: 0.0,
            jitter_m: 0.0,
            drop_share: 0.0,
            low_conf_share: 0.0,
            yaw_deg: 0.0,
            units_per_metre: 1.0,
            seed: 0,
        }
    }
    /// What a monocular 3D estimator gives on rehearsal footage, roughly:
    /// 15 mm noise, 2 % of points off by 8 cm, 3 % of frames missed, 5 % in
    /// low-confidence spells, millimetre units.
    pub fn noisy(layout: Layout, fps: f64, seed: u64) -> Self {
        SynthOptions {
            noise_m: 0.015,
            jitter_share: 0.02,
            jitter_m: 0.08,
            drop_share: 0.03,
            low_conf_share: 0.05,
            units_per_metre: 1000.0,
            seed,
            ..SynthOptions::clean(layout, fps)
        }
    }
}

/// A standard normal draw (Box–Muller); also the trainer's context noise.
pub(crate) fn gaussian(rng: &mut impl Rng) -> f64 {
    let u1: f64 = rng.gen_range(f64::EPSILON..1.0);
    let u2: f64 = rng.gen::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Mark runs covering about `share` of `frames` frames, each `min..=max` long.
fn spells(rng: &mut impl Rng, frames: usize, share: f64, min: usize, max: usize) -> Vec<bool> {
    let mut on = vec![false; frames];
    let target = (share * frames as f64).round() as usize;
    let mut covered = 0;
    let mut tries = 0;
    while covered < target && tries < 10_000 && frames > max {
        tries += 1;
        let len = rng.gen_range(min..=max).min(target - covered).max(1);
        let start = rng.gen_range(0..frames - len);
        for f in start..start + len {
            if !on[f] {
                on[f] = true;
                covered += 1;
            }
        }
    }
    on
}

/// Keypoints made from an SMPL motion by forward kinematics, in the
/// layout's camera convention (y down, z away from the camera), resampled
/// to `opts.fps`, then degraded as `opts` says.
pub fn synthesize(m: &Motion, opts: &SynthOptions) -> Result<Keypoints, MotionError> {
    if m.skeleton.kind != "smpl24" {
        return Err(MotionError::invalid(
            &m.name,
            "skeleton",
            "keypoints are made from an SMPL-24 motion",
        ));
    }
    let m = m.resample(opts.fps)?;
    let markers = opts.layout.markers();
    let k = markers.len();
    let pos = m.positions();
    let glob = m.global_quats();
    let cam = quat_mul(
        quat_conj(opts.layout.default_up().to_y_up()),
        axis_angle_to_quat([0.0, opts.yaw_deg.to_radians(), 0.0]),
    );
    let frames = m.frames();
    let mut rng = rand::rngs::StdRng::seed_from_u64(opts.seed);
    let dropped = spells(&mut rng, frames, opts.drop_share, 2, 12);
    let low = spells(&mut rng, frames, opts.low_conf_share, 5, 20);
    let mut points = Vec::with_capacity(frames * k);
    let mut confidence = Vec::with_capacity(frames * k);
    for f in 0..frames {
        let j = m.joints();
        let pts = marker_points(
            &markers,
            &pos[f * j..(f + 1) * j],
            &glob[f * j..(f + 1) * j],
        );
        for p in pts {
            if dropped[f] {
                points.push([f64::NAN; 3]);
                confidence.push(0.0);
                continue;
            }
            let sigma = opts.noise_m * if low[f] { 3.0 } else { 1.0 };
            let mut q = quat_rotate(cam, p);
            for c in q.iter_mut() {
                *c += sigma * gaussian(&mut rng);
            }
            if opts.jitter_share > 0.0 && rng.gen::<f64>() < opts.jitter_share {
                let d = [gaussian(&mut rng), gaussian(&mut rng), gaussian(&mut rng)];
                q = add(
                    q,
                    scale(normalize(d).unwrap_or([1.0, 0.0, 0.0]), opts.jitter_m),
                );
            }
            points.push(scale(q, opts.units_per_metre));
            confidence.push(if low[f] {
                rng.gen_range(0.1..0.4)
            } else {
                rng.gen_range(0.85..1.0)
            });
        }
    }
    Ok(Keypoints {
        layout: opts.layout,
        fps: opts.fps,
        points,
        confidence,
    })
}
