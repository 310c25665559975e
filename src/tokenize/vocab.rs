//! The language model's vocabulary and frame layout (SPEC §4, thesis 000
//! §4.5.2, Fig. 4.8). Shared by the trainer and the server through JSON.
//!
//! A motion is reduced to the 13-joint SMPL subset at 20 fps. Each frame
//! ("word") is 43 tokens:
//!
//! | slots  | what |
//! |--------|------|
//! | 0–38   | the 13 joints' axis-angle components (x, y, z per joint, Table A.1 order), uniform bins over [−π, π] |
//! | 39, 40 | root ground-plane velocity (m/s), uniform bins over `velocity_range`: x, z in the scene's axes, or (`root_velocity: heading`) sideways, forward in the pelvis's heading |
//! | 41     | root (pelvis) height above the clip's floor (m), uniform bins over `height_range` |
//! | 42     | the separator |
//!
//! The floor of a clip is the lowest joint of the 13 over the whole clip
//! (the ankles, usually); velocities are backward differences (the first
//! frame's is 0), so decoding starts the root above the origin.
//!
//! Token ids: `0..bins` are value bins (shared by every value slot); then
//! the specials `<sep> <mask> <pad> <bos>`; then one class token
//! `<cls:KIND>` per label kind; then one conditioning token `<KIND=VALUE>`
//! per known label value. Kinds and values are kept sorted, so the ids are
//! a pure function of the JSON.

use super::UniformBins;
use crate::features::as_smpl13;
use crate::motion::rotation::{wrap_axis_angle, Vec3};
use crate::motion::{Labels, Motion, MotionError, Skeleton};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};

pub const VOCAB_VERSION: u32 = 1;
pub const SPECIALS: [&str; 4] = ["<sep>", "<mask>", "<pad>", "<bos>"];

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Vocabulary {
    pub version: u32,
    /// Bins per value slot (angles and root alike).
    pub bins: usize,
    /// Frames per second of the token stream.
    pub fps: f64,
    /// Skeleton kind of decoded motions (`smpl13`).
    pub skeleton: String,
    pub joints: Vec<String>,
    /// Root ground-plane velocity range, m/s.
    pub velocity_range: [f64; 2],
    /// Root height range above the floor, m.
    pub height_range: [f64; 2],
    /// Label kind → known values.
    pub labels: BTreeMap<String, BTreeSet<String>>,
    /// The axes the root velocity slots are read in. Absent in the JSON
    /// of every vocabulary before it existed, which means `world`.
    #[serde(default, skip_serializing_if = "RootVelocity::is_world")]
    pub root_velocity: RootVelocity,
}

/// The axes of the root's ground velocity slots (39, 40).
///
/// - `world`: x and z of the scene. Running forward is a different pair
///   of tokens for every direction the body faces, and the model must
///   work out the facing from the pelvis's axis-angle tokens to predict it.
/// - `heading`: sideways (+x to the body's left) and forward, in the
///   frame of the pelvis's heading (its forward axis projected on the
///   ground) at the same frame, read from the pelvis's *quantised*
///   rotation so encoding and decoding turn by the same angle. Running
///   forward is one token pair whichever way the body faces; the heading
///   itself stays in the pelvis's rotation slots.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RootVelocity {
    #[default]
    World,
    Heading,
}

impl RootVelocity {
    pub fn is_world(&self) -> bool {
        *self == RootVelocity::World
    }
    pub fn parse(s: &str) -> Result<RootVelocity, String> {
        match s {
            "world" => Ok(RootVelocity::World),
            "heading" => Ok(RootVelocity::Heading),
            other => Err(format!("{other:?}: want world or heading")),
        }
    }
}

/// The heading (yaw about +y, radians) of a pelvis axis-angle: the angle
/// of its forward axis (+z) projected on the ground, or, for a body lying
/// along y (forward nearly vertical), of its sideways axis turned a
/// quarter.
pub fn heading_of(pelvis: Vec3) -> f64 {
    let m = crate::motion::rotation::axis_angle_to_mat(pelvis);
    let f = crate::motion::rotation::mat_vec(&m, [0.0, 0.0, 1.0]);
    if f[0].hypot(f[2]) > 0.2 {
        return f[0].atan2(f[2]);
    }
    let r = crate::motion::rotation::mat_vec(&m, [1.0, 0.0, 0.0]);
    // +x (left) is forward turned +90° about y: forward = x turned -90°.
    r[0].atan2(r[2]) - std::f64::consts::FRAC_PI_2
}

/// A ground vector (x, z) turned by `yaw` about +y.
pub(crate) fn turn(v: (f64, f64), yaw: f64) -> (f64, f64) {
    let (s, c) = yaw.sin_cos();
    (v.0 * c + v.1 * s, -v.0 * s + v.1 * c)
}

/// What a token id stands for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Token {
    Value(u32),
    Sep,
    Mask,
    Pad,
    Bos,
    Class(String),
    Label(String, String),
}

impl Vocabulary {
    /// The default layout (360 bins, 20 fps, SMPL-13) with these labels.
    pub fn new(labels: BTreeMap<String, BTreeSet<String>>) -> Vocabulary {
        Vocabulary {
            version: VOCAB_VERSION,
            bins: 360,
            fps: 20.0,
            skeleton: "smpl13".into(),
            joints: Skeleton::smpl13().names,
            velocity_range: [-4.0, 4.0],
            height_range: [-0.5, 2.0],
            labels,
            root_velocity: RootVelocity::World,
        }
    }

    /// The labels of a set of motions, gathered for [`Vocabulary::new`].
    pub fn labels_of<'a>(
        motions: impl IntoIterator<Item = &'a Labels>,
    ) -> BTreeMap<String, BTreeSet<String>> {
        let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for l in motions {
            for (k, v) in l {
                out.entry(k.clone()).or_default().insert(v.clone());
            }
        }
        out
    }

    pub fn validate(&self) -> Result<(), MotionError> {
        let bad =
            |field: &str, reason: String| Err(MotionError::invalid("vocabulary", field, reason));
        if self.version != VOCAB_VERSION {
            return bad(
                "version",
                format!("{} (this build reads {VOCAB_VERSION})", self.version),
            );
        }
        if !(2..=65_536).contains(&self.bins) {
            return bad("bins", format!("{}; need 2..=65536", self.bins));
        }
        if !(self.fps > 0.0 && self.fps <= 1000.0) {
            return bad("fps", format!("{}; need (0, 1000]", self.fps));
        }
        match self.skeleton_def() {
            Some(sk) if self.joints == sk.names => {}
            _ => {
                return bad(
                    "joints",
                    format!(
                        "skeleton {:?} with {} joints: only SMPL-13 and SMPL-24 with their joint lists are supported",
                        self.skeleton,
                        self.joints.len()
                    ),
                )
            }
        }
        for (name, r) in [
            ("velocity_range", self.velocity_range),
            ("height_range", self.height_range),
        ] {
            UniformBins::new(self.bins, r[0], r[1]).map_err(|_| {
                MotionError::invalid(
                    "vocabulary",
                    name,
                    format!("{r:?} is not a finite range lo < hi"),
                )
            })?;
        }
        for (k, vs) in &self.labels {
            if k.is_empty() || k.contains(['=', ':', '<', '>']) {
                return bad(
                    "labels",
                    format!("kind '{k}' is empty or holds one of = : < >"),
                );
            }
            if vs.iter().any(|v| v.is_empty() || v.contains('>')) {
                return bad(
                    "labels",
                    format!("kind '{k}' has an empty value or one with '>'"),
                );
            }
        }
        Ok(())
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("vocabulary serialises")
    }

    pub fn from_json(text: &str, file: &str) -> Result<Vocabulary, MotionError> {
        let v: Vocabulary = serde_json::from_str(text)
            .map_err(|e| MotionError::invalid(file, "vocabulary", e.to_string()))?;
        v.validate().map_err(|e| e.in_file(file))?;
        Ok(v)
    }

    /// The vocabulary's skeleton (`smpl13`, or `smpl24` for the thesis's
    /// Table 4.5 comparison).
    pub fn skeleton_def(&self) -> Option<Skeleton> {
        match self.skeleton.as_str() {
            "smpl13" => Some(Skeleton::smpl13()),
            "smpl24" => Some(Skeleton::smpl24()),
            _ => None,
        }
    }

    /// The same layout on the full 24-joint SMPL skeleton.
    pub fn with_smpl24(mut self) -> Vocabulary {
        self.skeleton = "smpl24".into();
        self.joints = Skeleton::smpl24().names;
        self
    }

    /// Value slots a frame has (joints × 3 + 3).
    pub fn values_per_frame(&self) -> usize {
        self.joints.len() * 3 + 3
    }
    /// Tokens a frame takes, the separator included (43).
    pub fn frame_len(&self) -> usize {
        self.values_per_frame() + 1
    }
    pub fn sep(&self) -> u32 {
        self.bins as u32
    }
    pub fn mask(&self) -> u32 {
        self.bins as u32 + 1
    }
    pub fn pad(&self) -> u32 {
        self.bins as u32 + 2
    }
    pub fn bos(&self) -> u32 {
        self.bins as u32 + 3
    }
    fn class_base(&self) -> u32 {
        (self.bins + SPECIALS.len()) as u32
    }
    fn label_base(&self) -> u32 {
        self.class_base() + self.labels.len() as u32
    }
    pub fn size(&self) -> usize {
        self.label_base() as usize + self.labels.values().map(|v| v.len()).sum::<usize>()
    }

    pub fn class_token(&self, kind: &str) -> Result<u32, MotionError> {
        self.labels
            .keys()
            .position(|k| k == kind)
            .map(|i| self.class_base() + i as u32)
            .ok_or_else(|| self.unknown_kind(kind))
    }

    fn unknown_kind(&self, kind: &str) -> MotionError {
        MotionError::invalid(
            "labels",
            kind,
            format!(
                "unknown label kind; the vocabulary knows {:?}",
                self.labels.keys().collect::<Vec<_>>()
            ),
        )
    }

    pub fn label_token(&self, kind: &str, value: &str) -> Result<u32, MotionError> {
        let mut id = self.label_base();
        for (k, vs) in &self.labels {
            if k == kind {
                return vs
                    .iter()
                    .position(|v| v == value)
                    .map(|i| id + i as u32)
                    .ok_or_else(|| {
                        MotionError::invalid(
                            "labels",
                            kind,
                            format!("'{value}' was not seen in training; known: {vs:?}"),
                        )
                    });
            }
            id += vs.len() as u32;
        }
        Err(self.unknown_kind(kind))
    }

    pub fn token(&self, id: u32) -> Option<Token> {
        let b = self.bins as u32;
        if id < b {
            return Some(Token::Value(id));
        }
        match id - b {
            0 => return Some(Token::Sep),
            1 => return Some(Token::Mask),
            2 => return Some(Token::Pad),
            3 => return Some(Token::Bos),
            _ => {}
        }
        if id < self.label_base() {
            let k = self.labels.keys().nth((id - self.class_base()) as usize)?;
            return Some(Token::Class(k.clone()));
        }
        let mut rest = (id - self.label_base()) as usize;
        for (k, vs) in &self.labels {
            if rest < vs.len() {
                return Some(Token::Label(k.clone(), vs.iter().nth(rest)?.clone()));
            }
            rest -= vs.len();
        }
        None
    }

    /// A readable name for a token id.
    pub fn token_name(&self, id: u32) -> String {
        match self.token(id) {
            Some(Token::Value(v)) => v.to_string(),
            Some(Token::Sep) => SPECIALS[0].into(),
            Some(Token::Mask) => SPECIALS[1].into(),
            Some(Token::Pad) => SPECIALS[2].into(),
            Some(Token::Bos) => SPECIALS[3].into(),
            Some(Token::Class(k)) => format!("<cls:{k}>"),
            Some(Token::Label(k, v)) => format!("<{k}={v}>"),
            None => format!("<invalid:{id}>"),
        }
    }

    /// `<bos>` then one conditioning token per given label (kind order).
    /// Labels of kinds the vocabulary does not have are errors, as are
    /// unseen values.
    pub fn prefix(&self, labels: &Labels) -> Result<Vec<u32>, MotionError> {
        let mut out = vec![self.bos()];
        for (k, v) in labels {
            out.push(self.label_token(k, v)?);
        }
        Ok(out)
    }

    /// The labels of a motion that this vocabulary can condition on (others
    /// dropped), for building training prefixes.
    pub fn known_labels(&self, labels: &Labels) -> Labels {
        labels
            .iter()
            .filter(|(k, v)| self.labels.get(*k).is_some_and(|vs| vs.contains(*v)))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect()
    }

    /// The joint-angle slots' bins.
    pub fn angle_bins(&self) -> UniformBins {
        UniformBins::angles(self.bins)
    }
    /// The root ground-velocity slots' bins (m/s).
    pub fn velocity_bins(&self) -> UniformBins {
        UniformBins {
            bins: self.bins,
            lo: self.velocity_range[0],
            hi: self.velocity_range[1],
        }
    }
    fn height_bins(&self) -> UniformBins {
        UniformBins {
            bins: self.bins,
            lo: self.height_range[0],
            hi: self.height_range[1],
        }
    }

    /// The slot of a position inside a frame (0..43), counting from the
    /// first frame token (Fig. 4.8's joint index).
    pub fn slot(&self, pos_in_frames: usize) -> usize {
        pos_in_frames % self.frame_len()
    }

    /// Token ids allowed at a slot: `0..bins` for values, `<sep>` last.
    pub fn allowed(&self, slot: usize) -> std::ops::Range<u32> {
        if slot + 1 == self.frame_len() {
            self.sep()..self.sep() + 1
        } else {
            0..self.bins as u32
        }
    }

    /// A motion in the token stream's form: SMPL-13 at the vocabulary's
    /// fps (retargeted and resampled as needed).
    pub fn prepare(&self, m: &Motion) -> Result<Motion, MotionError> {
        let m13 = if self.skeleton == "smpl24" {
            match m.skeleton.kind.as_str() {
                "smpl24" => m.clone(),
                _ => as_smpl13(m)?.smpl13_to_smpl24()?,
            }
        } else {
            as_smpl13(m)?
        };
        if (m13.fps - self.fps).abs() > 1e-9 {
            m13.resample(self.fps)
        } else {
            Ok(m13)
        }
    }

    /// The frames of a motion as tokens (`frames × 43`, each frame ending in
    /// `<sep>`), no prefix.
    pub fn encode_motion(&self, m: &Motion) -> Result<Vec<u32>, MotionError> {
        self.encode_motion_on_floor(m, None).map(|(t, _)| t)
    }

    /// [`Vocabulary::encode_motion`] with the floor given (a live stream
    /// only sees a few frames at a time, so it keeps the lowest floor seen
    /// so far) or, when `None`, the clip's own. Returns the tokens and the
    /// floor used (the lower of the given one and this clip's).
    pub fn encode_motion_on_floor(
        &self,
        m: &Motion,
        floor: Option<f64>,
    ) -> Result<(Vec<u32>, f64), MotionError> {
        let m = self.prepare(m)?;
        let j = m.joints();
        let pos = m.positions();
        let own = pos.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
        let floor = floor.map_or(own, |f| f.min(own));
        let o = m.skeleton.offsets[0];
        let root = |t: usize| -> Vec3 {
            let tr = m.trans[t];
            [o[0] + tr[0], o[1] + tr[1], o[2] + tr[2]]
        };
        let (ab, vb, hb) = (self.angle_bins(), self.velocity_bins(), self.height_bins());
        let mut out = Vec::with_capacity(m.frames() * self.frame_len());
        for t in 0..m.frames() {
            for r in m.frame_rotations(t) {
                let w = wrap_axis_angle(*r);
                out.extend(w.iter().map(|&v| ab.encode(v)));
            }
            debug_assert_eq!(j * 3, self.joints.len() * 3);
            let (p, q) = (root(t), root(t.saturating_sub(1)));
            let v = ((p[0] - q[0]) * m.fps, (p[2] - q[2]) * m.fps);
            let v = match self.root_velocity {
                RootVelocity::World => v,
                RootVelocity::Heading => {
                    let n = self.joints.len();
                    let pelvis = &out[out.len() - 3 * n..out.len() - 3 * n + 3];
                    turn(v, -self.pelvis_heading(pelvis))
                }
            };
            out.push(vb.encode(v.0));
            out.push(vb.encode(v.1));
            out.push(hb.encode(p[1] - floor));
            out.push(self.sep());
        }
        Ok((out, floor))
    }

    /// The token of a root ground-plane velocity (m/s).
    pub fn encode_root_velocity(&self, v: f64) -> u32 {
        self.velocity_bins().encode(v)
    }

    /// A frame's root velocity tokens (x, z).
    pub fn root_velocity_tokens(&self, frame: &[u32]) -> (u32, u32) {
        let nj = self.joints.len();
        (frame[3 * nj], frame[3 * nj + 1])
    }

    /// The root's ground-plane velocity in the scene's axes (x, z, m/s) a
    /// frame's tokens carry (turned by the frame's pelvis heading where the
    /// slots are heading-relative).
    pub fn decode_root_velocity(&self, frame: &[u32]) -> (f64, f64) {
        let nj = self.joints.len();
        let vb = self.velocity_bins();
        let v = (vb.decode(frame[3 * nj]), vb.decode(frame[3 * nj + 1]));
        match self.root_velocity {
            RootVelocity::World => v,
            RootVelocity::Heading => turn(v, self.pelvis_heading(&frame[..3])),
        }
    }

    /// The heading of a frame's pelvis rotation tokens (slots 0–2).
    fn pelvis_heading(&self, tokens: &[u32]) -> f64 {
        let ab = self.angle_bins();
        heading_of([
            ab.decode(tokens[0]),
            ab.decode(tokens[1]),
            ab.decode(tokens[2]),
        ])
    }

    /// Decode a token stream into a motion. A leading `<bos>` and
    /// conditioning / class tokens are skipped; then whole frames are read
    /// (a trailing partial frame is dropped). A frame whose value slots hold
    /// a non-value token, or whose last slot is not `<sep>`, is an error
    /// naming the frame and slot.
    pub fn decode_motion(&self, tokens: &[u32], name: &str) -> Result<Motion, MotionError> {
        let start = tokens
            .iter()
            .position(|&t| {
                !matches!(
                    self.token(t),
                    Some(Token::Bos | Token::Label(..) | Token::Class(_))
                )
            })
            .unwrap_or(tokens.len());
        let body = &tokens[start..];
        let fl = self.frame_len();
        let frames = body.len() / fl;
        if frames == 0 {
            return Err(MotionError::invalid(
                name,
                "tokens",
                format!(
                    "no whole frame ({} tokens after the prefix, a frame is {fl})",
                    body.len()
                ),
            ));
        }
        let sk = self.skeleton_def().ok_or_else(|| {
            MotionError::invalid(name, "vocabulary.skeleton", self.skeleton.clone())
        })?;
        let o = sk.offsets[0];
        let (ab, hb) = (self.angle_bins(), self.height_bins());
        let nj = self.joints.len();
        let mut rots = Vec::with_capacity(frames * nj);
        let mut trans = Vec::with_capacity(frames);
        let (mut x, mut z) = (0.0, 0.0);
        for f in 0..frames {
            let w = &body[f * fl..(f + 1) * fl];
            for (s, &t) in w.iter().enumerate() {
                let ok = if s + 1 == fl {
                    t == self.sep()
                } else {
                    t < self.bins as u32
                };
                if !ok {
                    return Err(MotionError::invalid(
                        name,
                        format!("tokens: frame {f}, slot {s}"),
                        format!("{} is not allowed here", self.token_name(t)),
                    ));
                }
            }
            for k in 0..nj {
                rots.push([
                    ab.decode(w[3 * k]),
                    ab.decode(w[3 * k + 1]),
                    ab.decode(w[3 * k + 2]),
                ]);
            }
            if f > 0 {
                let (vx, vz) = self.decode_root_velocity(w);
                x += vx / self.fps;
                z += vz / self.fps;
            }
            let h = hb.decode(w[3 * nj + 2]);
            trans.push([x - o[0], h - o[1], z - o[2]]);
        }
        Motion::new(name, self.fps, sk, trans, rots, Labels::new())
    }
}

#[cfg(test)]
mod tests;
