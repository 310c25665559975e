//! Keypoints from video pose estimators, and inverse kinematics onto SMPL.
//!
//! A [`Layout`] names what each keypoint is (Human3.6M's 17 joints as
//! MotionBERT and VideoPose3D write them; MediaPipe Pose's 33 world
//! landmarks) and defines it as a point on the SMPL neutral body: a joint,
//! or a point fixed in a joint's frame (the nose, the ears, the fingertips).
//! The same definitions serve both ways: [`synthesize`] makes keypoints from
//! a real SMPL take (forward kinematics, then a camera, noise, jitter,
//! dropped frames and low-confidence spells), and [`solve`] turns keypoints
//! back into SMPL-24 rotations, its rest references taken from the same
//! points on the rest body.
//!
//! What the inverse kinematics can and cannot see:
//! - Bone directions are observed; twist about a bone is not. The knees and
//!   elbows are treated as hinges about an axis measured on real dance
//!   ([`KNEE_AXIS`], [`ELBOW_AXIS`]), which fixes the twist of the hip and the
//!   shoulder above them whenever the limb is bent; on a straight limb the
//!   twist is the least rotation and is not recovered.
//! - Ankles and wrists need a point beyond them (MediaPipe's heel/toe and
//!   fingers); Human3.6M-17 has none, so they stay at rest. Collars and the
//!   head stay at rest; the spine's bend is shared equally by its three
//!   joints, the neck takes the direction to the head.
//! - Scale comes from the bone lengths (thighs, shins, upper arms, forearms
//!   against the SMPL neutral body), so millimetres, centimetres or an
//!   estimator's own units all work.
//! - A frame whose body keypoints are missing (NaN, no detection) or below
//!   the confidence threshold is flagged and bridged: rotations by SLERP
//!   between the nearest good frames, the root by linear interpolation.

use super::clip::{Labels, Motion, MAX_FPS, MAX_FRAMES};
use super::rotation::*;
use super::skeleton::Skeleton;
use super::MotionError;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The keypoint sets choreo reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// Human3.6M's 17 joints (MotionBERT, VideoPose3D): pelvis, right
    /// hip/knee/ankle, left hip/knee/ankle, spine, thorax, nose, head top,
    /// left shoulder/elbow/wrist, right shoulder/elbow/wrist.
    H36m17,
    /// MediaPipe Pose's 33 world landmarks.
    Mediapipe33,
}

pub const H36M17_NAMES: [&str; 17] = [
    "pelvis",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_hip",
    "left_knee",
    "left_ankle",
    "spine",
    "thorax",
    "nose",
    "head",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
];

pub const MEDIAPIPE33_NAMES: [&str; 33] = [
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
];

/// A keypoint as a point of the SMPL body: a joint, or a point fixed in a
/// joint's frame (metres, SMPL rest axes: x left, y up, z forward).
#[derive(Clone, Copy, Debug)]
enum Marker {
    Joint(usize),
    Offset(usize, Vec3),
}

/// Which keypoints (averaged) stand for each body point the solver uses.
/// Pairs are `[left, right]`.
struct Semantic {
    pelvis: &'static [usize],
    hip: [&'static [usize]; 2],
    knee: [&'static [usize]; 2],
    ankle: [&'static [usize]; 2],
    toe: Option<[&'static [usize]; 2]>,
    shoulder: [&'static [usize]; 2],
    elbow: [&'static [usize]; 2],
    wrist: [&'static [usize]; 2],
    hand: Option<[&'static [usize]; 2]>,
    thorax: &'static [usize],
    /// A point on the lower back (Human3.6M's "spine"), when the layout
    /// has one: nearer the pelvis than the thorax, it tells the pelvis's
    /// tilt with less of the spine's bend in it.
    spine: Option<&'static [usize]>,
    head: &'static [usize],
}

impl Layout {
    pub fn name(self) -> &'static str {
        match self {
            Layout::H36m17 => "h36m17",
            Layout::Mediapipe33 => "mediapipe33",
        }
    }
    pub fn names(self) -> &'static [&'static str] {
        match self {
            Layout::H36m17 => &H36M17_NAMES,
            Layout::Mediapipe33 => &MEDIAPIPE33_NAMES,
        }
    }
    pub fn len(self) -> usize {
        self.names().len()
    }
    /// Share of the torso's tilt [`solve`] gives the pelvis (the spine
    /// takes the rest), chosen on the first 40 AIST++-VRM dances: measured
    /// from the lower back (Human3.6M) or from the thorax (MediaPipe).
    pub fn pelvis_share(self) -> f64 {
        match self {
            Layout::H36m17 => H36M_PELVIS_SHARE,
            Layout::Mediapipe33 => PELVIS_SHARE,
        }
    }

    /// The up axis of what the estimators write: both write camera
    /// coordinates with y pointing down the image (x right, z away from the
    /// camera), so up is −y.
    pub fn default_up(self) -> Up {
        Up::NegY
    }

    fn markers(self) -> Vec<Marker> {
        use Marker::*;
        match self {
            Layout::H36m17 => vec![
                Joint(0),
                Joint(2),
                Joint(5),
                Joint(8),
                Joint(1),
                Joint(4),
                Joint(7),
                Joint(6),
                Joint(12),
                Offset(15, [0.0, 0.0, 0.10]),
                Offset(15, [0.0, 0.12, 0.0]),
                Joint(16),
                Joint(18),
                Joint(20),
                Joint(17),
                Joint(19),
                Joint(21),
            ],
            Layout::Mediapipe33 => {
                let head = |x: f64, y: f64, z: f64| Offset(15, [x, y, z]);
                vec![
                    head(0.0, 0.0, 0.10),
                    head(0.015, 0.035, 0.09),
                    head(0.03, 0.035, 0.085),
                    head(0.045, 0.035, 0.075),
                    head(-0.015, 0.035, 0.09),
                    head(-0.03, 0.035, 0.085),
                    head(-0.045, 0.035, 0.075),
                    head(0.075, 0.02, 0.0),
                    head(-0.075, 0.02, 0.0),
                    head(0.025, -0.03, 0.09),
                    head(-0.025, -0.03, 0.09),
                    Joint(16),
                    Joint(17),
                    Joint(18),
                    Joint(19),
                    Joint(20),
                    Joint(21),
                    Offset(20, [0.09, 0.0, -0.03]),
                    Offset(21, [-0.09, 0.0, -0.03]),
                    Offset(20, [0.09, 0.0, 0.03]),
                    Offset(21, [-0.09, 0.0, 0.03]),
                    Offset(20, [0.05, 0.0, 0.05]),
                    Offset(21, [-0.05, 0.0, 0.05]),
                    Joint(1),
                    Joint(2),
                    Joint(4),
                    Joint(5),
                    Joint(7),
                    Joint(8),
                    Offset(7, [0.0, -0.05, -0.05]),
                    Offset(8, [0.0, -0.05, -0.05]),
                    Offset(10, [0.0, 0.0, 0.04]),
                    Offset(11, [0.0, 0.0, 0.04]),
                ]
            }
        }
    }

    fn semantic(self) -> Semantic {
        match self {
            Layout::H36m17 => Semantic {
                pelvis: &[0],
                hip: [&[4], &[1]],
                knee: [&[5], &[2]],
                ankle: [&[6], &[3]],
                toe: None,
                shoulder: [&[11], &[14]],
                elbow: [&[12], &[15]],
                wrist: [&[13], &[16]],
                hand: None,
                thorax: &[8],
                spine: Some(&[7]),
                head: &[10],
            },
            Layout::Mediapipe33 => Semantic {
                pelvis: &[23, 24],
                hip: [&[23], &[24]],
                knee: [&[25], &[26]],
                ankle: [&[27], &[28]],
                toe: Some([&[31], &[32]]),
                shoulder: [&[11], &[12]],
                elbow: [&[13], &[14]],
                wrist: [&[15], &[16]],
                hand: Some([&[17, 19], &[18, 20]]),
                thorax: &[11, 12],
                spine: None,
                head: &[7, 8],
            },
        }
    }

    /// The keypoints the solver needs in every frame (the rest, e.g. the
    /// face, may be missing without flagging the frame).
    fn core(self) -> Vec<usize> {
        let s = self.semantic();
        let mut v: Vec<usize> = [s.pelvis, s.thorax, s.head]
            .into_iter()
            .chain(s.spine)
            .chain(s.hip)
            .chain(s.knee)
            .chain(s.ankle)
            .chain(s.shoulder)
            .chain(s.elbow)
            .chain(s.wrist)
            .flatten()
            .copied()
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }
}

impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Layout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "h36m17" | "h36m" => Ok(Layout::H36m17),
            "mediapipe33" | "mediapipe" => Ok(Layout::Mediapipe33),
            other => Err(format!(
                "unknown keypoint layout {other:?}: expected h36m17 or mediapipe33"
            )),
        }
    }
}

/// Which axis of a file points up. choreo's world is y up; the turn is a
/// proper rotation, so handedness is kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Up {
    #[serde(rename = "y")]
    Y,
    #[serde(rename = "-y")]
    NegY,
    #[serde(rename = "z")]
    Z,
    #[serde(rename = "-z")]
    NegZ,
    #[serde(rename = "x")]
    X,
    #[serde(rename = "-x")]
    NegX,
}

impl Up {
    pub fn name(self) -> &'static str {
        match self {
            Up::Y => "y",
            Up::NegY => "-y",
            Up::Z => "z",
            Up::NegZ => "-z",
            Up::X => "x",
            Up::NegX => "-x",
        }
    }
    /// The rotation taking this axis onto +y: a half turn about x for −y,
    /// a quarter turn about x for ±z, about z for ±x.
    pub fn to_y_up(self) -> Quat {
        use std::f64::consts::{FRAC_PI_2, PI};
        match self {
            Up::Y => IDENTITY_QUAT,
            Up::NegY => axis_angle_to_quat([PI, 0.0, 0.0]),
            Up::Z => axis_angle_to_quat([-FRAC_PI_2, 0.0, 0.0]),
            Up::NegZ => axis_angle_to_quat([FRAC_PI_2, 0.0, 0.0]),
            Up::X => axis_angle_to_quat([0.0, 0.0, FRAC_PI_2]),
            Up::NegX => axis_angle_to_quat([0.0, 0.0, -FRAC_PI_2]),
        }
    }
}

impl fmt::Display for Up {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Up {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "y" | "+y" => Ok(Up::Y),
            "-y" => Ok(Up::NegY),
            "z" | "+z" => Ok(Up::Z),
            "-z" => Ok(Up::NegZ),
            "x" | "+x" => Ok(Up::X),
            "-x" => Ok(Up::NegX),
            other => Err(format!(
                "unknown up axis {other:?}: expected y, -y, z, -z, x or -x"
            )),
        }
    }
}

/// Keypoints of one person: `points` and `confidence` are `[frames][layout]`
/// frame-major. A missing point is NaN with confidence 0.
#[derive(Clone, Debug, PartialEq)]
pub struct Keypoints {
    pub layout: Layout,
    pub fps: f64,
    pub points: Vec<Vec3>,
    pub confidence: Vec<f64>,
}

impl Keypoints {
    pub fn frames(&self) -> usize {
        self.points.len() / self.layout.len().max(1)
    }
    fn at(&self, f: usize, ids: &[usize]) -> (Vec3, f64) {
        let k = self.layout.len();
        let mut p = [0.0; 3];
        let mut c = f64::INFINITY;
        for &i in ids {
            p = add(p, self.points[f * k + i]);
            c = c.min(self.confidence[f * k + i]);
        }
        (scale(p, 1.0 / ids.len() as f64), c)
    }
}

/// Share of frames that may be missing before a file is refused.
pub const MAX_MISSING_SHARE: f64 = 0.5;
/// Default confidence below which a frame is flagged.
pub const DEFAULT_MIN_CONFIDENCE: f64 = 0.5;

/// What the solver found about a file's frames.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FootageReport {
    pub layout: String,
    pub frames: usize,
    /// Frames flagged (missing or below the confidence threshold) and
    /// bridged.
    pub flagged_frames: usize,
    /// The flagged runs as `[first frame, frame count]`.
    pub gaps: Vec<[usize; 2]>,
    /// Metres per file unit, from the bone lengths.
    pub metres_per_unit: f64,
    pub mean_confidence: f64,
    /// Per-frame confidence (the least of the body keypoints'), 0 where
    /// flagged for missing points.
    #[serde(skip)]
    pub confidence: Vec<f32>,
    pub up: String,
    pub min_confidence: f64,
    /// Keypoint smoothing used (Gaussian σ, seconds).
    pub smooth_s: f64,
    /// The video frame the motion's first frame is (SMPL files' first
    /// `frame_ids`; 0 for keypoint files, whose rows are the video's frames).
    pub first_frame: usize,
}

/// The knee's hinge axis in the hip's frame (left, right): the principal
/// axis of the knees' local rotations over the first 40 AIST++-VRM dances
/// (sorted by name; evaluations leave them out), 84–86 % of the axes'
/// spread. (Turning it so that the bend plane sits at the shin's median
/// bend direction measured worse on held-out dances: 3.5° against 1.3°.)
pub const KNEE_AXIS: [Vec3; 2] = [[0.931, 0.014, -0.364], [0.951, -0.004, 0.308]];
/// The elbow's hinge axis in the shoulder's frame (left, right), measured
/// the same way (74–81 % of the spread). SMPL fits spread the forearm's bend
/// direction widely about the upper arm (interquartile range about 60°):
/// the upper arm's twist is not seen, and the elbow inherits its error.
pub const ELBOW_AXIS: [Vec3; 2] = [[-0.097, -0.913, -0.397], [-0.083, 0.929, 0.362]];

/// SMPL-24 joint indices of the limbs: (upper, mid, end, beyond) per side.
const LEG: [[usize; 4]; 2] = [[1, 4, 7, 10], [2, 5, 8, 11]];
const ARM: [[usize; 4]; 2] = [[16, 18, 20, 22], [17, 19, 21, 23]];
const SPINE: [usize; 3] = [3, 6, 9];
const NECK: usize = 12;

/// Marker positions of one posed body, `[layout]`, from global joint
/// positions and rotations.
fn marker_points(markers: &[Marker], pos: &[Vec3], glob: &[Quat]) -> Vec<Vec3> {
    markers
        .iter()
        .map(|m| match *m {
            Marker::Joint(j) => pos[j],
            Marker::Offset(j, o) => add(pos[j], quat_rotate(glob[j], o)),
        })
        .collect()
}

/// The layout's points on the SMPL neutral body at rest.
fn rest_points(layout: Layout) -> Vec<Vec3> {
    let sk = Skeleton::smpl24();
    let pos = Motion::rest_positions(&sk);
    marker_points(&layout.markers(), &pos, &vec![IDENTITY_QUAT; sk.len()])
}

fn mean_of(points: &[Vec3], ids: &[usize]) -> Vec3 {
    let mut p = [0.0; 3];
    for &i in ids {
        p = add(p, points[i]);
    }
    scale(p, 1.0 / ids.len() as f64)
}

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

fn gaussian(rng: &mut impl Rng) -> f64 {
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

/// How [`joint_errors`] measures a joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Measure {
    /// The bone's direction in its parent's frame (the joint's own twist
    /// excluded). For knees and elbows this includes the parent's twist
    /// about its bone, which keypoints do not show: the error then says how
    /// far the solver's choice of thigh / upper-arm twist is from the one
    /// the mocap fit happened to make.
    ParentFrame,
    /// What keypoints can show: for knees and elbows the bone's direction
    /// in the parent's frame with the parent's twist removed too (the
    /// least rotation carrying the parent bone from rest); other joints as
    /// [`Measure::ParentFrame`].
    Observable,
}

/// Per-joint IK error, degrees, of `solved` against `truth` (both SMPL-24,
/// same frames), on the SMPL-13 joints: for each joint that bends a bone the
/// angle between the bone's directions as `measure` says; for the pelvis the
/// whole rotation. Returns `(joint name, errors over frames)`; joints whose
/// bone the layout does not observe are left out.
pub fn joint_errors(
    layout: Layout,
    solved: &Motion,
    truth: &Motion,
    measure: Measure,
) -> Vec<(String, Vec<f64>)> {
    let sk = Skeleton::smpl24();
    let frames = solved.frames().min(truth.frames());
    let s13 = |m: &Motion| m.to_smpl13().ok();
    let (Some(a), Some(b)) = (s13(solved), s13(truth)) else {
        return Vec::new();
    };
    let sem = layout.semantic();
    let rest = Motion::rest_positions(&sk);
    let dir = |from: usize, to: usize| normalize(sub(rest[to], rest[from]));
    // (13-joint index, its bone's rest direction, the parent's (13-joint
    // index, bone direction) for knees and elbows)
    type Spec = (usize, Option<Vec3>, Option<(usize, Vec3)>);
    let mut joints: Vec<Spec> = vec![(0, None, None)];
    for side in 0..2 {
        let (leg, arm) = (LEG[side], ARM[side]);
        let thigh = dir(leg[0], leg[1]).expect("rest bone");
        let upper = dir(arm[0], arm[1]).expect("rest bone");
        joints.push((1 + side, Some(thigh), None));
        joints.push((3 + side, dir(leg[1], leg[2]), Some((1 + side, thigh))));
        if sem.toe.is_some() {
            joints.push((5 + side, dir(leg[2], leg[3]), None));
        }
        joints.push((7 + side, Some(upper), None));
        joints.push((9 + side, dir(arm[1], arm[2]), Some((7 + side, upper))));
        if sem.hand.is_some() {
            joints.push((11 + side, dir(arm[2], arm[3]), None));
        }
    }
    joints.sort_by_key(|j| j.0);
    let names = Skeleton::smpl13().names;
    let seen = |m: &Motion, f: usize, j: usize, d: Vec3, parent: Option<(usize, Vec3)>| {
        let local = quat_rotate(axis_angle_to_quat(m.rot(f, j)), d);
        match (measure, parent) {
            (Measure::Observable, Some((p, pd))) => {
                let lp = axis_angle_to_quat(m.rot(f, p));
                let swing = quat_between(pd, quat_rotate(lp, pd));
                quat_rotate(quat_conj(swing), quat_rotate(lp, local))
            }
            _ => local,
        }
    };
    joints
        .into_iter()
        .map(|(j, d, parent)| {
            let errs = (0..frames)
                .map(|f| match d {
                    None => geodesic_quat(
                        axis_angle_to_quat(a.rot(f, j)),
                        axis_angle_to_quat(b.rot(f, j)),
                    )
                    .to_degrees(),
                    Some(d) => dot(seen(&a, f, j, d, parent), seen(&b, f, j, d, parent))
                        .clamp(-1.0, 1.0)
                        .acos()
                        .to_degrees(),
                })
                .collect();
            (names[j].clone(), errs)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bent_motion() -> Motion {
        // A body with bent knees and elbows, a turned pelvis and a bent spine.
        let mut rots = vec![[0.0; 3]; 24 * 3];
        for f in 0..3 {
            let t = f as f64 * 0.2;
            rots[f * 24] = [0.2 + t, 0.5, 0.1];
            rots[f * 24 + 1] = [-0.6, 0.1, 0.2];
            rots[f * 24 + 2] = [-0.3, -0.1, -0.1];
            for (j, a) in [(4, 1.0), (5, 0.7)] {
                rots[f * 24 + j] = scale(normalize(KNEE_AXIS[j - 4]).unwrap(), a + t);
            }
            for (j, a) in [(18, 1.2), (19, 0.8)] {
                rots[f * 24 + j] = scale(normalize(ELBOW_AXIS[j - 18]).unwrap(), a);
            }
            rots[f * 24 + 16] = [0.1, 0.3, -0.8];
            rots[f * 24 + 17] = [0.0, -0.2, 0.9];
            for j in SPINE {
                rots[f * 24 + j] = [0.1, 0.05, 0.0];
            }
        }
        Motion::new(
            "bent",
            30.0,
            Skeleton::smpl24(),
            vec![[0.1, 0.9, -0.2]; 3],
            rots,
            Labels::new(),
        )
        .unwrap()
    }

    #[test]
    fn up_axes_turn_onto_y() {
        for (up, v) in [
            (Up::Y, [0.0, 1.0, 0.0]),
            (Up::NegY, [0.0, -1.0, 0.0]),
            (Up::Z, [0.0, 0.0, 1.0]),
            (Up::NegZ, [0.0, 0.0, -1.0]),
            (Up::X, [1.0, 0.0, 0.0]),
            (Up::NegX, [-1.0, 0.0, 0.0]),
        ] {
            let r = quat_rotate(up.to_y_up(), v);
            assert!(norm(sub(r, [0.0, 1.0, 0.0])) < 1e-12, "{up}: {r:?}");
            assert_eq!(up.name().parse::<Up>().unwrap(), up);
        }
    }

    #[test]
    fn clean_keypoints_give_back_the_bone_directions() {
        let m = bent_motion();
        for layout in [Layout::H36m17, Layout::Mediapipe33] {
            let mut o = SynthOptions::clean(layout, 30.0);
            o.units_per_metre = 1000.0;
            let kp = synthesize(&m, &o).unwrap();
            let o = SolveOptions {
                smooth_s: 0.0,
                ..SolveOptions::new(layout)
            };
            let (solved, rep) = solve("bent", &kp, &o).unwrap();
            assert!((rep.metres_per_unit - 0.001).abs() < 1e-9, "{rep:?}");
            assert_eq!(rep.flagged_frames, 0);
            // Hinge joints come back exactly (their parents' twist is fixed
            // by the bend); every limb bone points where it pointed.
            for (name, errs) in joint_errors(layout, &solved, &m, Measure::ParentFrame) {
                let worst = errs.iter().cloned().fold(0.0, f64::max);
                if name.contains("Knee") || name.contains("Elbow") {
                    assert!(worst < 0.5, "{layout} {name}: {worst:.3}°");
                }
            }
            let (ps, pt) = (solved.positions(), m.positions());
            for f in 0..3 {
                for (a, b) in [
                    (1, 4),
                    (4, 7),
                    (2, 5),
                    (5, 8),
                    (16, 18),
                    (18, 20),
                    (17, 19),
                    (19, 21),
                ] {
                    let u = normalize(sub(ps[f * 24 + b], ps[f * 24 + a])).unwrap();
                    let v = normalize(sub(pt[f * 24 + b], pt[f * 24 + a])).unwrap();
                    let deg = dot(u, v).clamp(-1.0, 1.0).acos().to_degrees();
                    assert!(deg < 0.5, "{layout} bone {a}->{b}: {deg:.3}°");
                }
            }
            // The pelvis point lands where its keypoint is (H36M's is the
            // root joint; MediaPipe's the hips' midpoint).
            let (ps, pt) = (solved.positions(), m.positions());
            let mid = |p: &[Vec3], ids: &[usize]| mean_of(p, ids);
            let ids: &[usize] = match layout {
                Layout::H36m17 => &[0],
                Layout::Mediapipe33 => &[1, 2],
            };
            let d = norm(sub(mid(&ps[..24], ids), mid(&pt[..24], ids)));
            assert!(d < 1e-6, "{layout}: pelvis point off by {d} m");
        }
    }

    #[test]
    fn gaps_are_bridged_and_too_many_refused() {
        let m = bent_motion();
        let mut kp = synthesize(&m, &SynthOptions::clean(Layout::H36m17, 30.0)).unwrap();
        for p in &mut kp.points[17..34] {
            *p = [f64::NAN; 3];
        }
        let o = SolveOptions::new(Layout::H36m17);
        let (solved, rep) = solve("gap", &kp, &o).unwrap();
        assert_eq!(rep.gaps, vec![[1, 1]]);
        let a = axis_angle_to_quat(solved.rot(0, 4));
        let c = axis_angle_to_quat(solved.rot(2, 4));
        let mid = axis_angle_to_quat(solved.rot(1, 4));
        assert!(geodesic_quat(mid, slerp(a, c, 0.5)) < 1e-9);
        for p in &mut kp.points[..17] {
            *p = [f64::NAN; 3];
        }
        let e = solve("gap", &kp, &o).unwrap_err().to_string();
        assert!(
            e.contains("gap: field `frames`") && e.contains("2 of 3"),
            "{e}"
        );
    }
}
