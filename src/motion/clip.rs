//! The canonical motion type and its operations.
//!
//! Shapes: `rotations` is `[frames][joints]` local axis-angle (radians),
//! stored frame-major in one `Vec`; `trans` is `[frames]` root translation in
//! metres (y up). The root joint's world position is
//! `skeleton.offsets[0] + trans[f]` (the SMPL convention).
//!
//! Mutation is visible: every op here takes `&self` and returns a new motion.

use super::rotation::*;
use super::skeleton::{Skeleton, SMPL13_FROM_24};
use super::MotionError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Labels by kind: `genre`, `dancer`, `situation`, `music`, `tempo_bpm`,
/// `choreography`, `content`, `style`, `corpus`.
pub type Labels = BTreeMap<String, String>;

/// Hard ceilings that protect every reader and op from absurd inputs.
pub const MAX_FRAMES: usize = 10_000_000;
pub const MAX_JOINTS: usize = 1024;
pub const MAX_FPS: f64 = 10_000.0;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Motion {
    /// Where it came from (file path or a given name); used in error messages.
    pub name: String,
    /// Frames per second.
    pub fps: f64,
    pub skeleton: Skeleton,
    /// `[frames]` root translation, metres.
    pub trans: Vec<Vec3>,
    /// `[frames][joints]` local axis-angle, frame-major.
    pub rotations: Vec<Vec3>,
    pub labels: Labels,
}

impl Motion {
    /// Build and validate.
    pub fn new(
        name: impl Into<String>,
        fps: f64,
        skeleton: Skeleton,
        trans: Vec<Vec3>,
        rotations: Vec<Vec3>,
        labels: Labels,
    ) -> Result<Self, MotionError> {
        let m = Motion {
            name: name.into(),
            fps,
            skeleton,
            trans,
            rotations,
            labels,
        };
        m.validate()?;
        Ok(m)
    }

    pub fn frames(&self) -> usize {
        self.trans.len()
    }
    pub fn joints(&self) -> usize {
        self.skeleton.len()
    }
    /// `(frames - 1) / fps`: the time from the first frame to the last.
    pub fn duration_s(&self) -> f64 {
        if self.frames() == 0 {
            0.0
        } else {
            (self.frames() - 1) as f64 / self.fps
        }
    }
    pub fn rot(&self, frame: usize, joint: usize) -> Vec3 {
        self.rotations[frame * self.joints() + joint]
    }
    /// The local rotations of one frame, `[joints]`.
    pub fn frame_rotations(&self, frame: usize) -> &[Vec3] {
        let j = self.joints();
        &self.rotations[frame * j..(frame + 1) * j]
    }

    pub fn validate(&self) -> Result<(), MotionError> {
        let file = self.name.as_str();
        self.skeleton.validate().map_err(|e| e.in_file(file))?;
        if !(self.fps.is_finite() && self.fps > 0.0 && self.fps <= MAX_FPS) {
            return Err(MotionError::invalid(
                file,
                "fps",
                format!("{} is not a frame rate in (0, {MAX_FPS}]", self.fps),
            ));
        }
        if self.joints() > MAX_JOINTS {
            return Err(MotionError::invalid(
                file,
                "joints",
                format!("{} joints is over the limit of {MAX_JOINTS}", self.joints()),
            ));
        }
        if self.frames() == 0 {
            return Err(MotionError::invalid(
                file,
                "frames",
                "the motion has no frames",
            ));
        }
        if self.frames() > MAX_FRAMES {
            return Err(MotionError::invalid(
                file,
                "frames",
                format!("{} frames is over the limit of {MAX_FRAMES}", self.frames()),
            ));
        }
        if self.rotations.len() != self.frames() * self.joints() {
            return Err(MotionError::invalid(
                file,
                "rotations",
                format!(
                    "expected {} frames x {} joints = {} rotations, found {}",
                    self.frames(),
                    self.joints(),
                    self.frames() * self.joints(),
                    self.rotations.len()
                ),
            ));
        }
        if let Some(i) = self
            .trans
            .iter()
            .position(|t| t.iter().any(|v| !v.is_finite()))
        {
            return Err(MotionError::invalid(
                file,
                "trans",
                format!("frame {i} has a NaN or infinite root translation"),
            ));
        }
        if let Some(i) = self
            .rotations
            .iter()
            .position(|r| r.iter().any(|v| !v.is_finite()))
        {
            let j = self.joints();
            return Err(MotionError::invalid(
                file,
                "rotations",
                format!(
                    "frame {} joint {} ('{}') has a NaN or infinite rotation",
                    i / j,
                    i % j,
                    self.skeleton.names[i % j]
                ),
            ));
        }
        Ok(())
    }

    /// Global joint rotations as quaternions, `[frames][joints]`.
    pub fn global_quats(&self) -> Vec<Quat> {
        let j = self.joints();
        let mut out = Vec::with_capacity(self.rotations.len());
        for f in 0..self.frames() {
            let base = out.len();
            for k in 0..j {
                let local = axis_angle_to_quat(self.rotations[f * j + k]);
                let g = match self.skeleton.parents[k] {
                    None => local,
                    Some(p) => quat_mul(out[base + p], local),
                };
                out.push(g);
            }
        }
        out
    }

    /// Forward kinematics: joint positions in metres, `[frames][joints]`.
    pub fn positions(&self) -> Vec<Vec3> {
        let mut pos = Vec::with_capacity(self.rotations.len());
        let mut glob: Vec<Quat> = vec![IDENTITY_QUAT; self.joints()];
        for f in 0..self.frames() {
            frame_fk(
                &self.skeleton,
                self.frame_rotations(f),
                self.trans[f],
                &mut glob,
                &mut pos,
            );
        }
        pos
    }

    /// Joint positions of the rest pose (all local rotations identity, no
    /// translation), `[joints]`.
    pub fn rest_positions(skeleton: &Skeleton) -> Vec<Vec3> {
        let mut pos: Vec<Vec3> = Vec::with_capacity(skeleton.len());
        for k in 0..skeleton.len() {
            match skeleton.parents[k] {
                None => pos.push(skeleton.offsets[k]),
                Some(p) => pos.push(add(pos[p], skeleton.offsets[k])),
            }
        }
        pos
    }

    /// A copy with other rotations and translations (same skeleton, fps, labels).
    pub fn with_data(&self, trans: Vec<Vec3>, rotations: Vec<Vec3>) -> Motion {
        Motion {
            name: self.name.clone(),
            fps: self.fps,
            skeleton: self.skeleton.clone(),
            trans,
            rotations,
            labels: self.labels.clone(),
        }
    }

    /// Frames `[start, end)`.
    pub fn cut(&self, start: usize, end: usize) -> Result<Motion, MotionError> {
        if start >= end || end > self.frames() {
            return Err(MotionError::invalid(
                &self.name,
                "range",
                format!(
                    "frames [{start}, {end}) are not a non-empty range inside 0..{}",
                    self.frames()
                ),
            ));
        }
        let j = self.joints();
        Ok(self.with_data(
            self.trans[start..end].to_vec(),
            self.rotations[start * j..end * j].to_vec(),
        ))
    }

    /// Resample to `fps`: rotations by quaternion SLERP, translation by lerp.
    /// The new clip spans the same time from the first frame: `floor(duration
    /// * fps) + 1` frames.
    pub fn resample(&self, fps: f64) -> Result<Motion, MotionError> {
        if !(fps.is_finite() && fps > 0.0 && fps <= MAX_FPS) {
            return Err(MotionError::invalid(
                &self.name,
                "fps",
                format!("{fps} is not a frame rate in (0, {MAX_FPS}]"),
            ));
        }
        if (fps - self.fps).abs() < 1e-9 {
            return Ok(self.clone());
        }
        let n_new = (self.duration_s() * fps + 1e-6).floor() as usize + 1;
        if n_new > MAX_FRAMES {
            return Err(MotionError::invalid(
                &self.name,
                "fps",
                format!("resampling to {fps} fps would give {n_new} frames, over the limit"),
            ));
        }
        let j = self.joints();
        let last = self.frames() - 1;
        let mut trans = Vec::with_capacity(n_new);
        let mut rots = Vec::with_capacity(n_new * j);
        for i in 0..n_new {
            let s = i as f64 * self.fps / fps;
            let f0 = (s.floor() as usize).min(last);
            let f1 = (f0 + 1).min(last);
            let t = (s - f0 as f64).clamp(0.0, 1.0);
            if t < 1e-9 || f0 == f1 {
                trans.push(self.trans[f0]);
                rots.extend_from_slice(self.frame_rotations(f0));
                continue;
            }
            trans.push(lerp3(self.trans[f0], self.trans[f1], t));
            for k in 0..j {
                let qa = axis_angle_to_quat(self.rot(f0, k));
                let qb = axis_angle_to_quat(self.rot(f1, k));
                rots.push(quat_to_axis_angle(slerp(qa, qb, t)));
            }
        }
        let mut m = self.with_data(trans, rots);
        m.fps = fps;
        Ok(m)
    }

    /// The 13 joints of thesis 000 Table A.1 from an SMPL-24 motion. Each kept
    /// joint's new local rotation is the product of the local rotations along
    /// the dropped chain above it, so kept joints keep their global
    /// orientation (the rest offsets are folded the same way).
    pub fn to_smpl13(&self) -> Result<Motion, MotionError> {
        match self.skeleton.kind.as_str() {
            "smpl13" => return Ok(self.clone()),
            "smpl24" => {}
            other => {
                return Err(MotionError::invalid(
                    &self.name,
                    "skeleton",
                    format!(
                        "the 13-joint subset needs an SMPL-24 motion, this one is '{other}' (retarget it first)"
                    ),
                ))
            }
        }
        let sk13 = Skeleton::smpl13();
        let full = &self.skeleton;
        let j = self.joints();
        let mut rots = Vec::with_capacity(self.frames() * 13);
        for f in 0..self.frames() {
            for &k in SMPL13_FROM_24.iter() {
                let mut q = axis_angle_to_quat(self.rotations[f * j + k]);
                let mut p = full.parents[k];
                while let Some(pi) = p {
                    if SMPL13_FROM_24.contains(&pi) {
                        break;
                    }
                    q = quat_mul(axis_angle_to_quat(self.rotations[f * j + pi]), q);
                    p = full.parents[pi];
                }
                rots.push(quat_to_axis_angle(q));
            }
        }
        // The root offset is the same joint's, so the translation carries over.
        let mut m = self.with_data(self.trans.clone(), rots);
        m.skeleton = sk13;
        Ok(m)
    }

    /// Back to SMPL-24 from the 13-joint subset: dropped joints get the
    /// identity rotation.
    pub fn smpl13_to_smpl24(&self) -> Result<Motion, MotionError> {
        if self.skeleton.kind != "smpl13" {
            return Err(MotionError::invalid(
                &self.name,
                "skeleton",
                "expected an smpl13 motion",
            ));
        }
        let mut rots = vec![[0.0; 3]; self.frames() * 24];
        for f in 0..self.frames() {
            for (i, &k) in SMPL13_FROM_24.iter().enumerate() {
                rots[f * 24 + k] = self.rot(f, i);
            }
        }
        let mut m = self.with_data(self.trans.clone(), rots);
        m.skeleton = Skeleton::smpl24();
        Ok(m)
    }

    /// The axis (0 = x, 1 = y, 2 = z) across which the rest pose's left and
    /// right joints lie; `None` when the skeleton has no named pairs.
    pub fn lateral_axis(skeleton: &Skeleton) -> Option<usize> {
        let pairs = skeleton.mirror_pairs();
        if pairs.is_empty() {
            return None;
        }
        let rest = Motion::rest_positions(skeleton);
        let mut spread = [0.0f64; 3];
        for (a, b) in pairs {
            for (k, s) in spread.iter_mut().enumerate() {
                *s += (rest[a][k] - rest[b][k]).abs();
            }
        }
        let axis = (0..3).max_by(|&x, &y| spread[x].total_cmp(&spread[y]))?;
        (spread[axis] > 1e-9).then_some(axis)
    }

    /// Bilateral mirror (thesis 000 §A.5): swap left/right joints and reflect
    /// across the skeleton's lateral plane. For SMPL (lateral axis x) each
    /// axis-angle `(x, y, z)` becomes `(x, −y, −z)`; the root's world position
    /// is reflected exactly (`x → −x`), so mirroring twice is the identity.
    pub fn mirror(&self) -> Result<Motion, MotionError> {
        let axis = Motion::lateral_axis(&self.skeleton).ok_or_else(|| {
            MotionError::invalid(
                &self.name,
                "skeleton",
                "no left/right joint pairs found by name, cannot mirror",
            )
        })?;
        let map = self.skeleton.mirror_map();
        let reflect = |v: Vec3| {
            let mut r = v;
            r[axis] = -r[axis];
            r
        };
        // Local reflection is only the physical mirror when each joint's rest
        // offset reflects onto its partner's (SMPL: yes; rigs whose right side
        // uses turned joint frames, like Bandai Namco's: no).
        for (a, &b) in map.iter().enumerate() {
            let (oa, ob) = (self.skeleton.offsets[a], self.skeleton.offsets[b]);
            if a != 0 && norm(sub(reflect(oa), ob)) > 0.2 * norm(oa) + 0.01 {
                return Err(MotionError::invalid(
                    &self.name,
                    "skeleton",
                    format!(
                        "rest pose is not mirror-symmetric ('{}' and '{}' have unmatched offsets); retarget to smpl13 first",
                        self.skeleton.names[a], self.skeleton.names[b]
                    ),
                ));
            }
        }
        // Reflection M: a rotation R becomes M R M, i.e. axis-angle v -> -M v.
        let reflect_rot = |v: Vec3| scale(reflect(v), -1.0);
        let j = self.joints();
        let mut rots = vec![[0.0; 3]; self.rotations.len()];
        for f in 0..self.frames() {
            for k in 0..j {
                rots[f * j + map[k]] = reflect_rot(self.rotations[f * j + k]);
            }
        }
        let o0 = self.skeleton.offsets[0];
        let trans = self
            .trans
            .iter()
            .map(|&t| sub(reflect(add(o0, t)), o0))
            .collect();
        Ok(self.with_data(trans, rots))
    }

    /// The facing direction on the ground plane (unit `[x, 0, z]`) at a frame,
    /// from the lowest-level left/right joint pair (the hips on a human): it is
    /// `(left − right) × up`. `None` when it cannot be told.
    pub fn facing(&self, frame: usize) -> Option<Vec3> {
        let pairs = self.skeleton.mirror_pairs();
        let depth = |mut k: usize| {
            let mut d = 0;
            while let Some(p) = self.skeleton.parents[k] {
                d += 1;
                k = p;
            }
            d
        };
        let &(a, b) = pairs.iter().min_by_key(|(a, _)| depth(*a))?;
        let (left, right) = if super::skeleton::is_left(&self.skeleton.names[a]) == Some(true) {
            (a, b)
        } else {
            (b, a)
        };
        let one = self.cut(frame, frame + 1).ok()?;
        let pos = one.positions();
        let lat = sub(pos[left], pos[right]);
        let fwd = cross(lat, [0.0, 1.0, 0.0]);
        normalize([fwd[0], 0.0, fwd[2]])
    }

    /// Root normalisation: the root starts above the origin (x = z = 0, height
    /// kept) and the body faces +z at the first frame (a rotation about y).
    pub fn normalize_root(&self) -> Result<Motion, MotionError> {
        let fwd = self.facing(0).ok_or_else(|| {
            MotionError::invalid(
                &self.name,
                "skeleton",
                "cannot tell which way the body faces (no left/right hips found)",
            )
        })?;
        let yaw = quat_between(fwd, [0.0, 0.0, 1.0]);
        let p0 = add(self.skeleton.offsets[0], self.trans[0]);
        Ok(self.turned(yaw, [p0[0], 0.0, p0[2]], [0.0; 3]))
    }

    /// The whole motion turned by `yaw` (a rotation about the vertical)
    /// about the point `from`, which then moves to `to`: the root's
    /// rotation and world path follow, every other joint is unchanged.
    pub(crate) fn turned(&self, yaw: Quat, from: Vec3, to: Vec3) -> Motion {
        let (o0, j) = (self.skeleton.offsets[0], self.joints());
        let mut rots = self.rotations.clone();
        for f in 0..self.frames() {
            let q = quat_mul(yaw, axis_angle_to_quat(rots[f * j]));
            rots[f * j] = quat_to_axis_angle(q);
        }
        let trans = self
            .trans
            .iter()
            .map(|&t| sub(add(quat_rotate(yaw, sub(add(o0, t), from)), to), o0))
            .collect();
        self.with_data(trans, rots)
    }
}

impl Motion {
    /// Repair single-frame capture glitches ("flips"): a run of at most
    /// `max_run` frames where a joint's rotation jumps more than
    /// `threshold` radians from the frame before the run while the frames on
    /// both sides of the run agree within `threshold / 2`, is replaced by a
    /// SLERP between those two frames (per joint). Returns the repaired
    /// motion and the number of (frame, joint) rotations replaced.
    pub fn despike(&self, max_run: usize, threshold: f64) -> (Motion, usize) {
        let (n, j) = (self.frames(), self.joints());
        let mut rots = self.rotations.clone();
        let mut fixed = 0;
        for k in 0..j {
            let q = |rots: &Vec<Vec3>, f: usize| axis_angle_to_quat(rots[f * j + k]);
            let mut t = 1;
            while t < n {
                let before = q(&rots, t - 1);
                if geodesic_quat(before, q(&rots, t)) <= threshold {
                    t += 1;
                    continue;
                }
                let back = (t + 1..(t + 1 + max_run).min(n))
                    .find(|&e| geodesic_quat(before, q(&rots, e)) <= threshold / 2.0);
                match back {
                    Some(e) => {
                        let after = q(&rots, e);
                        for f in t..e {
                            let a = (f - t + 1) as f64 / (e - t + 1) as f64;
                            rots[f * j + k] = quat_to_axis_angle(slerp(before, after, a));
                            fixed += 1;
                        }
                        t = e + 1;
                    }
                    None => t += 1,
                }
            }
        }
        (self.with_data(self.trans.clone(), rots), fixed)
    }
}

mod chain;
#[cfg(test)]
pub(crate) mod tests;

/// One frame's forward kinematics: each joint's global rotation written
/// to `glob` (one slot per joint) and its position (metres) appended to
/// `pos`. The step [`Motion::positions`] repeats over frames.
pub fn frame_fk(
    skeleton: &Skeleton,
    rotations: &[Vec3],
    trans: Vec3,
    glob: &mut [Quat],
    pos: &mut Vec<Vec3>,
) {
    let base = pos.len();
    for k in 0..skeleton.len() {
        let local = axis_angle_to_quat(rotations[k]);
        match skeleton.parents[k] {
            None => {
                glob[k] = local;
                pos.push(add(skeleton.offsets[k], trans));
            }
            Some(p) => {
                glob[k] = quat_mul(glob[p], local);
                let p_pos: Vec3 = pos[base + p];
                pos.push(add(p_pos, quat_rotate(glob[p], skeleton.offsets[k])));
            }
        }
    }
}
