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

mod measure;
mod solve;
mod synth;

pub use measure::{joint_errors, Measure};
pub use solve::{bridge, solve, SolveOptions, DEFAULT_SMOOTH_S, H36M_PELVIS_SHARE, PELVIS_SHARE};
#[cfg(feature = "train")]
pub(crate) use synth::gaussian;
pub use synth::{synthesize, SynthOptions};

use super::clip::Motion;
use super::rotation::*;
use super::skeleton::Skeleton;
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

#[cfg(test)]
mod tests;
