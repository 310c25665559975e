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
        let o0 = self.skeleton.offsets[0];
        let p0 = add(o0, self.trans[0]);
        let c = [p0[0], 0.0, p0[2]];
        let j = self.joints();
        let mut rots = self.rotations.clone();
        for f in 0..self.frames() {
            let q = quat_mul(yaw, axis_angle_to_quat(rots[f * j]));
            rots[f * j] = quat_to_axis_angle(q);
        }
        let trans = self
            .trans
            .iter()
            .map(|&t| sub(quat_rotate(yaw, sub(add(o0, t), c)), o0))
            .collect();
        Ok(self.with_data(trans, rots))
    }
}

impl Motion {
    /// Takes played one after another as one motion, each entering where
    /// it best goes on from the last: the next take starts at the frame
    /// after its pose nearest the chain's last pose (every joint but the
    /// root; searched over its first half, the root's ground speed counted
    /// too, in m/s against radians), is turned about the vertical to face
    /// as the chain faces, and is placed where the root's last ground
    /// velocity carries it over `bridge + 1` frames (its own height kept).
    /// The `bridge` frames between SLERP every joint and lerp the root, so
    /// a run goes on running and a still take stays still. The takes must
    /// share the first one's joints and frame rate; the chain has its
    /// skeleton, name and labels.
    pub fn chain(takes: &[Motion], bridge: usize) -> Result<Motion, MotionError> {
        let first = takes
            .first()
            .ok_or_else(|| MotionError::invalid("chain", "takes", "no take to chain"))?;
        let j = first.joints();
        let o0 = first.skeleton.offsets[0];
        let facing = |m: &Motion, f: usize| {
            m.facing(f).ok_or_else(|| {
                MotionError::invalid(
                    &m.name,
                    "skeleton",
                    "cannot tell which way the body faces (no left/right hips found)",
                )
            })
        };
        let ground = |p: Vec3| [p[0], 0.0, p[2]];
        let (mut trans, mut rots) = (first.trans.clone(), first.rotations.clone());
        for t in &takes[1..] {
            if t.skeleton.parents != first.skeleton.parents || (t.fps - first.fps).abs() > 1e-9 {
                return Err(MotionError::invalid(
                    &t.name,
                    "skeleton",
                    format!(
                        "its joints or frame rate differ from {}'s; only alike takes chain",
                        first.name
                    ),
                ));
            }
            if t.frames() < 2 {
                continue;
            }
            let last = trans.len() - 1;
            let step = if last > 0 {
                ground(sub(trans[last], trans[last - 1]))
            } else {
                [0.0; 3]
            };
            let to = |f: usize| norm(ground(sub(t.trans[f], t.trans[f - 1])));
            let cost = |f: usize| {
                let pose: f64 = (1..j)
                    .map(|k| geodesic_axis_angle(rots[last * j + k], t.rot(f - 1, k)))
                    .sum();
                pose + (to(f) - norm(step)).abs() * t.fps
            };
            let entry = (1..=(t.frames() / 2).max(1))
                .min_by(|&a, &b| cost(a).total_cmp(&cost(b)))
                .unwrap_or(1);
            let so_far = first.with_data(trans[last..].to_vec(), rots[last * j..].to_vec());
            let (fa, fb) = (facing(&so_far, 0)?, facing(t, entry - 1)?);
            let yaw = axis_angle_to_quat([0.0, cross(fb, fa)[1].atan2(dot(fb, fa)), 0.0]);
            let end = add(o0, trans[last]);
            let from = ground(add(t.skeleton.offsets[0], t.trans[entry]));
            let at = add(ground(end), scale(step, (bridge + 1) as f64));
            let next_trans: Vec<Vec3> = t.trans[entry..]
                .iter()
                .map(|&tr| {
                    let p = add(t.skeleton.offsets[0], tr);
                    sub(add(quat_rotate(yaw, sub(p, from)), at), o0)
                })
                .collect();
            let mut next_rots = t.rotations[entry * j..].to_vec();
            for f in 0..next_trans.len() {
                let q = quat_mul(yaw, axis_angle_to_quat(next_rots[f * j]));
                next_rots[f * j] = quat_to_axis_angle(q);
            }
            for i in 1..=bridge {
                let a = i as f64 / (bridge + 1) as f64;
                trans.push(lerp3(trans[last], next_trans[0], a));
                for k in 0..j {
                    let (qa, qb) = (
                        axis_angle_to_quat(rots[last * j + k]),
                        axis_angle_to_quat(next_rots[k]),
                    );
                    rots.push(quat_to_axis_angle(slerp(qa, qb, a)));
                }
            }
            trans.extend(next_trans);
            rots.extend(next_rots);
        }
        let out = first.with_data(trans, rots);
        out.validate()?;
        Ok(out)
    }

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
