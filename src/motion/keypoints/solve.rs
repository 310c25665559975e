//! Inverse kinematics: keypoints to SMPL-24 rotations ([`solve`]), and the
//! bridging of flagged frames.

use super::*;
use crate::motion::clip::{Labels, Motion, MAX_FPS, MAX_FRAMES};
use crate::motion::rotation::*;
use crate::motion::skeleton::Skeleton;
use crate::motion::MotionError;

/// The rotation taking the frame built from (`a`, `b`) at rest onto the one
/// built from the observed pair: first axis along `a`, second the part of
/// `b` orthogonal to it. `None` when either pair is (nearly) parallel.
fn triad(rest_a: Vec3, rest_b: Vec3, obs_a: Vec3, obs_b: Vec3) -> Option<Quat> {
    let frame = |a: Vec3, b: Vec3| -> Option<Mat3> {
        let e1 = normalize(a)?;
        let e2 = normalize(sub(b, scale(e1, dot(b, e1))))?;
        if norm(sub(b, scale(e1, dot(b, e1)))) < 1e-6 * norm(b).max(1e-12) {
            return None;
        }
        let e3 = cross(e1, e2);
        // Columns e1 e2 e3.
        Some([
            [e1[0], e2[0], e3[0]],
            [e1[1], e2[1], e3[1]],
            [e1[2], e2[2], e3[2]],
        ])
    };
    let r = frame(rest_a, rest_b)?;
    let o = frame(obs_a, obs_b)?;
    Some(quat_normalize(mat_to_quat(&mat_mul(&o, &transpose(&r)))))
}

fn scale_quat_angle(q: Quat, t: f64) -> Quat {
    axis_angle_to_quat(scale(quat_to_axis_angle(q), t))
}

/// A two-bone limb: the upper joint's local rotation and the mid joint's
/// hinge rotation that put the bones along `obs_a` (upper → mid) and
/// `obs_b` (mid → end), both given in the upper joint's parent frame.
/// `rest_a`/`rest_b` are the rest bone directions; `hinge` the mid joint's
/// axis.
fn limb(rest_a: Vec3, rest_b: Vec3, obs_a: Vec3, obs_b: Vec3, hinge: Vec3) -> (Quat, Quat) {
    let (Some(ra), Some(rb), Some(oa), Some(ob), Some(h)) = (
        normalize(rest_a),
        normalize(rest_b),
        normalize(obs_a),
        normalize(obs_b),
        normalize(hinge),
    ) else {
        return (IDENTITY_QUAT, IDENTITY_QUAT);
    };
    // The hinge angle θ that gives the observed angle between the bones:
    // ra · R(h, θ) rb = cos φ, i.e. A cos θ + B sin θ + C = cos φ.
    let cos_phi = dot(oa, ob).clamp(-1.0, 1.0);
    let hb = dot(h, rb);
    let ha = dot(h, ra);
    let a = dot(ra, rb) - hb * ha;
    let b = dot(ra, cross(h, rb));
    let c = hb * ha;
    let amp = (a * a + b * b).sqrt();
    let theta = if amp < 1e-9 {
        0.0
    } else {
        let delta = b.atan2(a);
        // The flexion branch (θ ≥ δ, where the limb is straightest).
        delta + ((cos_phi - c) / amp).clamp(-1.0, 1.0).acos()
    };
    let mid = axis_angle_to_quat(scale(h, theta));
    let bent = quat_rotate(mid, rb);
    let swing = quat_between(ra, oa);
    // On a (nearly) straight limb the bend plane says nothing about the
    // upper bone's twist: fade from the hinge-fixed twist to the least
    // rotation below 15° of bend.
    let sin_obs = norm(cross(oa, ob));
    let w = (sin_obs / 15f64.to_radians().sin()).clamp(0.0, 1.0);
    let upper = match triad(ra, bent, oa, ob) {
        Some(q) if w > 0.0 => slerp(swing, q, w),
        _ => swing,
    };
    // Where the hinge cannot put the lower bone exactly (a straight limb's
    // faded twist, an angle past the hinge's reach), the least extra
    // rotation does; on a bent limb it is the identity.
    let corr = quat_between(bent, quat_rotate(quat_conj(upper), ob));
    (upper, quat_mul(corr, mid))
}

/// The least rotation taking `rest` onto `obs` (a joint whose bone ends in
/// one observed point).
fn swing_to(rest: Vec3, obs: Vec3) -> Quat {
    match (normalize(rest), normalize(obs)) {
        (Some(r), Some(o)) => quat_between(r, o),
        _ => IDENTITY_QUAT,
    }
}

/// The fixed parts of the solve for one layout.
struct Solver {
    sem: Semantic,
    rest: Vec<Vec3>,
    /// Share of the torso's pitch and roll given to the pelvis (the rest
    /// goes to the spine).
    pelvis_share: f64,
}

/// Share of the torso's tilt (pelvis → thorax) the pelvis takes when no
/// lower-back point is seen (the spine takes the rest).
pub const PELVIS_SHARE: f64 = 0.5;
/// The same share, measured from Human3.6M's lower-back point (on the 40
/// fitting dances, clean keypoints: pelvis median 3.61° at 0.5, 3.44° at
/// 0.75, 3.38° at 1; from the thorax at 0.5 it was 4.09°). The test
/// keypoints place that point at SMPL's Spine2; a real estimator's sits
/// about there.
pub const H36M_PELVIS_SHARE: f64 = 1.0;

impl Solver {
    fn new(layout: Layout, pelvis_share: f64) -> Self {
        Solver {
            sem: layout.semantic(),
            rest: rest_points(layout),
            pelvis_share,
        }
    }

    fn rp(&self, ids: &[usize]) -> Vec3 {
        mean_of(&self.rest, ids)
    }

    /// One frame's SMPL-24 local rotations from its points (world, y up).
    fn frame(&self, p: &dyn Fn(&[usize]) -> Vec3) -> Vec<Quat> {
        let s = &self.sem;
        let mut local = vec![IDENTITY_QUAT; 24];
        // Pelvis: the hip line exactly, then a share of the tilt that brings
        // the rest "up" (pelvis → lower back, else → thorax) onto the
        // observed one.
        let rest_hips = sub(self.rp(s.hip[0]), self.rp(s.hip[1]));
        let obs_hips = sub(p(s.hip[0]), p(s.hip[1]));
        let rest_up = sub(self.rp(s.thorax), self.rp(s.pelvis));
        let obs_up = sub(p(s.thorax), p(s.pelvis));
        let back = s.spine.unwrap_or(s.thorax);
        let full = triad(
            rest_hips,
            sub(self.rp(back), self.rp(s.pelvis)),
            obs_hips,
            sub(p(back), p(s.pelvis)),
        )
        .unwrap_or_else(|| swing_to(rest_hips, obs_hips));
        let hip_only = swing_to(rest_hips, obs_hips);
        // Rotation about the hip line from `hip_only` to `full`, scaled.
        let extra = quat_mul(quat_conj(hip_only), full);
        let pelvis = quat_mul(hip_only, scale_quat_angle(extra, self.pelvis_share));
        local[0] = pelvis;
        // Spine: the torso frame (shoulder line, pelvis → thorax) relative to
        // the pelvis, split evenly over Spine1..3.
        let rest_sh = sub(self.rp(s.shoulder[0]), self.rp(s.shoulder[1]));
        let obs_sh = sub(p(s.shoulder[0]), p(s.shoulder[1]));
        let torso = triad(rest_sh, rest_up, obs_sh, obs_up).unwrap_or(pelvis);
        let rel = quat_mul(quat_conj(pelvis), torso);
        let third = scale_quat_angle(rel, 1.0 / 3.0);
        for j in SPINE {
            local[j] = third;
        }
        let chest = quat_mul(pelvis, quat_mul(third, quat_mul(third, third)));
        // Neck: towards the head point.
        let rest_neck = sub(self.rp(s.head), self.rp(s.thorax));
        let obs_neck = quat_rotate(quat_conj(chest), sub(p(s.head), p(s.thorax)));
        local[NECK] = swing_to(rest_neck, obs_neck);
        // Limbs.
        for side in 0..2 {
            for (chain, parent, pts, axis, beyond) in [
                (
                    LEG[side],
                    pelvis,
                    [s.hip[side], s.knee[side], s.ankle[side]],
                    KNEE_AXIS[side],
                    s.toe.map(|t| t[side]),
                ),
                (
                    ARM[side],
                    chest,
                    [s.shoulder[side], s.elbow[side], s.wrist[side]],
                    ELBOW_AXIS[side],
                    s.hand.map(|h| h[side]),
                ),
            ] {
                let inv = quat_conj(parent);
                let ra = sub(self.rp(pts[1]), self.rp(pts[0]));
                let rb = sub(self.rp(pts[2]), self.rp(pts[1]));
                let oa = quat_rotate(inv, sub(p(pts[1]), p(pts[0])));
                let ob = quat_rotate(inv, sub(p(pts[2]), p(pts[1])));
                let (upper, mid) = limb(ra, rb, oa, ob, axis);
                local[chain[0]] = upper;
                local[chain[1]] = mid;
                if let Some(end) = beyond {
                    let g_mid = quat_mul(parent, quat_mul(upper, mid));
                    let rest_e = sub(self.rp(end), self.rp(pts[2]));
                    let obs_e = quat_rotate(quat_conj(g_mid), sub(p(end), p(pts[2])));
                    local[chain[2]] = swing_to(rest_e, obs_e);
                }
            }
        }
        local
    }

    /// Metres per unit: the SMPL body's limb bone lengths over the observed
    /// ones (median over good frames).
    fn metres_per_unit(&self, kp: &Keypoints, good: &[bool]) -> Option<f64> {
        let s = &self.sem;
        let bones: Vec<(&[usize], &[usize])> = (0..2)
            .flat_map(|i| {
                [
                    (s.hip[i], s.knee[i]),
                    (s.knee[i], s.ankle[i]),
                    (s.shoulder[i], s.elbow[i]),
                    (s.elbow[i], s.wrist[i]),
                ]
            })
            .collect();
        let rest: f64 = bones
            .iter()
            .map(|(a, b)| norm(sub(self.rp(a), self.rp(b))))
            .sum();
        let mut ratios: Vec<f64> = (0..kp.frames())
            .filter(|&f| good[f])
            .map(|f| {
                let obs: f64 = bones
                    .iter()
                    .map(|(a, b)| norm(sub(kp.at(f, a).0, kp.at(f, b).0)))
                    .sum();
                rest / obs
            })
            .filter(|r| r.is_finite() && *r > 0.0)
            .collect();
        if ratios.is_empty() {
            return None;
        }
        ratios.sort_by(f64::total_cmp);
        Some(ratios[ratios.len() / 2])
    }
}

/// How [`solve`] reads keypoints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveOptions {
    /// The file's up axis.
    pub up: Up,
    /// Confidence below which a frame is flagged and bridged.
    pub min_confidence: f64,
    /// Share of the torso's tilt given to the pelvis.
    pub pelvis_share: f64,
    /// Temporal smoothing of the keypoints before the solve: the Gaussian's
    /// σ in seconds (after a 3-frame median that removes single-frame
    /// outliers); 0 turns both off.
    pub smooth_s: f64,
}

/// Default keypoint smoothing, seconds (σ): chosen with `choreo eval
/// footage --smooth` on the first 40 AIST++-VRM dances (noisy H36M-17
/// keypoints: median error 10.1° unsmoothed, 5.8° at 0.05 s, 5.6° at
/// 0.067 s, which costs clean keypoints 0.4° more).
pub const DEFAULT_SMOOTH_S: f64 = 0.05;

impl SolveOptions {
    pub fn new(layout: Layout) -> Self {
        SolveOptions {
            up: layout.default_up(),
            min_confidence: DEFAULT_MIN_CONFIDENCE,
            pelvis_share: layout.pelvis_share(),
            smooth_s: DEFAULT_SMOOTH_S,
        }
    }
}

/// Smooth every keypoint coordinate over the good frames: a median of 3
/// (single-frame outliers), then a Gaussian of σ `sigma` frames. Flagged
/// frames neither contribute nor change.
fn smooth(kp: &mut Keypoints, good: &[bool], sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let k = kp.layout.len();
    let frames = good.len();
    let radius = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|d| (-(d * d) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let mut col = vec![0.0f64; frames];
    let mut med = vec![0.0f64; frames];
    for i in 0..k {
        for c in 0..3 {
            for f in 0..frames {
                col[f] = kp.points[f * k + i][c];
            }
            let ok = |f: usize| good[f] && col[f].is_finite();
            for f in 0..frames {
                if !ok(f) {
                    med[f] = col[f];
                    continue;
                }
                let (a, b) = (
                    f.checked_sub(1).filter(|&g| ok(g)),
                    Some(f + 1).filter(|&g| g < frames && ok(g)),
                );
                med[f] = match (a, b) {
                    (Some(a), Some(b)) => {
                        let (x, y, z) = (col[a], col[f], col[b]);
                        x.max(y).min(x.min(y).max(z))
                    }
                    _ => col[f],
                };
            }
            for f in 0..frames {
                if !ok(f) {
                    continue;
                }
                let (mut sum, mut wsum) = (0.0, 0.0);
                for (wi, d) in (-radius..=radius).enumerate() {
                    let g = f as isize + d;
                    if g < 0 || g >= frames as isize || !ok(g as usize) {
                        continue;
                    }
                    sum += weights[wi] * med[g as usize];
                    wsum += weights[wi];
                }
                kp.points[f * k + i][c] = sum / wsum;
            }
        }
    }
}

/// Inverse kinematics: keypoints to an SMPL-24 motion at the keypoints' frame
/// rate. `file` names the source in errors.
pub fn solve(
    file: &str,
    kp: &Keypoints,
    opts: &SolveOptions,
) -> Result<(Motion, FootageReport), MotionError> {
    let SolveOptions {
        up,
        min_confidence,
        pelvis_share,
        smooth_s,
    } = *opts;
    if !(smooth_s.is_finite() && (0.0..=1.0).contains(&smooth_s)) {
        return Err(MotionError::invalid(
            file,
            "smooth_s",
            format!("{smooth_s} is not in [0, 1] seconds"),
        ));
    }
    let k = kp.layout.len();
    let frames = kp.frames();
    if frames == 0 || frames > MAX_FRAMES {
        return Err(MotionError::invalid(
            file,
            "frames",
            format!("{frames} frames is not in 1..={MAX_FRAMES}"),
        ));
    }
    if kp.points.len() != frames * k || kp.confidence.len() != frames * k {
        return Err(MotionError::invalid(
            file,
            "frames",
            format!("every frame needs {k} keypoints ({})", kp.layout),
        ));
    }
    if !(kp.fps.is_finite() && kp.fps > 0.0 && kp.fps <= MAX_FPS) {
        return Err(MotionError::invalid(
            file,
            "fps",
            format!("{} is not in (0, {MAX_FPS}]", kp.fps),
        ));
    }
    if !(0.0..=1.0).contains(&min_confidence) {
        return Err(MotionError::invalid(
            file,
            "min_confidence",
            format!("{min_confidence} is not in [0, 1]"),
        ));
    }
    let core = kp.layout.core();
    let mut conf = vec![0f32; frames];
    let good: Vec<bool> = (0..frames)
        .map(|f| {
            let mut c = f64::INFINITY;
            for &i in &core {
                let p = kp.points[f * k + i];
                if !p.iter().all(|v| v.is_finite()) {
                    return false;
                }
                c = c.min(kp.confidence[f * k + i]);
            }
            conf[f] = c as f32;
            c >= min_confidence
        })
        .collect();
    let n_good = good.iter().filter(|g| **g).count();
    let missing = frames - n_good;
    if n_good == 0 || missing as f64 > MAX_MISSING_SHARE * frames as f64 {
        return Err(MotionError::invalid(
            file,
            "frames",
            format!(
                "{missing} of {frames} frames have missing or low-confidence (< {min_confidence}) body keypoints; at most {:.0} % may",
                MAX_MISSING_SHARE * 100.0
            ),
        ));
    }
    let mut kp_s;
    let kp = if smooth_s > 0.0 {
        kp_s = kp.clone();
        smooth(&mut kp_s, &good, smooth_s * kp.fps);
        &kp_s
    } else {
        kp
    };
    let solver = Solver::new(kp.layout, pelvis_share);
    let mpu = solver.metres_per_unit(kp, &good).ok_or_else(|| {
        MotionError::invalid(file, "frames", "no frame has measurable bone lengths")
    })?;
    let turn = up.to_y_up();
    let pelvis_rest = Skeleton::smpl24().offsets[0];
    let mut rots: Vec<Vec3> = vec![[0.0; 3]; frames * 24];
    let mut trans: Vec<Vec3> = vec![[0.0; 3]; frames];
    for f in (0..frames).filter(|&f| good[f]) {
        let world = |ids: &[usize]| scale(quat_rotate(turn, kp.at(f, ids).0), mpu);
        let local = solver.frame(&world);
        for (j, q) in local.iter().enumerate() {
            rots[f * 24 + j] = quat_to_axis_angle(*q);
        }
        // The root joint sits where the pelvis point's rest offset from it,
        // turned with the pelvis, says (MediaPipe's "pelvis" is the hips'
        // midpoint, below SMPL's pelvis joint).
        let from_root = sub(solver.rp(solver.sem.pelvis), pelvis_rest);
        let root = sub(world(solver.sem.pelvis), quat_rotate(local[0], from_root));
        trans[f] = sub(root, pelvis_rest);
    }
    let gaps = bridge(&good, &mut rots, &mut trans);
    let motion = Motion::new(file, kp.fps, Skeleton::smpl24(), trans, rots, Labels::new())?;
    let mean_confidence = {
        let v: Vec<f64> = (0..frames)
            .filter(|&f| good[f])
            .map(|f| conf[f] as f64)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    Ok((
        motion,
        FootageReport {
            layout: kp.layout.name().into(),
            frames,
            flagged_frames: missing,
            gaps,
            metres_per_unit: mpu,
            mean_confidence,
            confidence: conf,
            up: up.name().into(),
            min_confidence,
            smooth_s,
            first_frame: 0,
        },
    ))
}

/// Fill flagged frames: rotations by SLERP between the nearest good frames,
/// the root by linear interpolation; leading and trailing runs hold the
/// nearest good frame. Returns the runs as `[first, count]`.
pub fn bridge(good: &[bool], rots: &mut [Vec3], trans: &mut [Vec3]) -> Vec<[usize; 2]> {
    let frames = good.len();
    let j = rots.len() / frames.max(1);
    let mut gaps = Vec::new();
    let mut f = 0;
    while f < frames {
        if good[f] {
            f += 1;
            continue;
        }
        let start = f;
        while f < frames && !good[f] {
            f += 1;
        }
        gaps.push([start, f - start]);
        let before = start.checked_sub(1);
        let after = (f < frames).then_some(f);
        for g in start..f {
            let (a, b, t) = match (before, after) {
                (Some(a), Some(b)) => (a, b, (g - a) as f64 / (b - a) as f64),
                (Some(a), None) => (a, a, 0.0),
                (None, Some(b)) => (b, b, 0.0),
                (None, None) => continue,
            };
            trans[g] = lerp3(trans[a], trans[b], t);
            for k in 0..j {
                let qa = axis_angle_to_quat(rots[a * j + k]);
                let qb = axis_angle_to_quat(rots[b * j + k]);
                rots[g * j + k] = quat_to_axis_angle(slerp(qa, qb, t));
            }
        }
    }
    gaps
}
