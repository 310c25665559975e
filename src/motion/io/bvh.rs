//! BVH: reader for any hierarchy and channel order, and a writer.
//!
//! Reading conventions (the ones Blender's importer uses):
//! - Rotation channels compose in the order listed, about the moving axes:
//!   `Zrotation Xrotation Yrotation` is `R = Rz Rx Ry` (degrees in the file).
//! - A joint with position channels takes them as its local translation in
//!   place of its `OFFSET`.
//! - A root whose single child carries its own translation (as in the Bandai
//!   Namco takes: `joint_Root` carries the travel, `Hips` the sway) is folded
//!   away: the child becomes the root, the two transforms composed per frame.
//! - A frame time within 0.01 % of a whole frame rate (0.0333333 s) is read as
//!   that rate (30 fps).
//! - Any other joint's position channels must be constant (they become its
//!   offset): choreo's motion model is root translation + joint rotations.
//! - Units become metres: by `BvhReadOptions::metres_per_unit`, or detected
//!   from the sum of bone lengths (see [`detect_unit`]).

use crate::motion::clip::{Motion, MAX_FRAMES, MAX_JOINTS};
use crate::motion::labels;
use crate::motion::rotation::*;
use crate::motion::skeleton::{EndSite, Skeleton};
use crate::motion::MotionError;
use serde::{Deserialize, Serialize};

mod write;
pub use write::{write_bvh, BvhWriteOptions};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Channel {
    Pos(Axis),
    Rot(Axis),
}

impl Channel {
    fn name(self) -> String {
        match self {
            Channel::Pos(a) => format!("{}position", a.letter()),
            Channel::Rot(a) => format!("{}rotation", a.letter()),
        }
    }
    fn parse(s: &str) -> Option<Channel> {
        if !s.is_ascii() || s.is_empty() {
            return None;
        }
        let (axis, kind) = s.split_at(1);
        let axis = match axis {
            "X" | "x" => Axis::X,
            "Y" | "y" => Axis::Y,
            "Z" | "z" => Axis::Z,
            _ => return None,
        };
        match kind.to_ascii_lowercase().as_str() {
            "position" => Some(Channel::Pos(axis)),
            "rotation" => Some(Channel::Rot(axis)),
            _ => None,
        }
    }
}

/// How a BVH file laid out its channels, kept so that writing a motion read
/// from BVH keeps each joint's rotation order and channel set.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BvhLayout {
    /// `(joint name, channels)` for every joint of the motion.
    pub joints: Vec<(String, Vec<Channel>)>,
    /// Metres per file unit used when reading.
    pub metres_per_unit: f64,
}

impl BvhLayout {
    fn channels_of(&self, name: &str) -> Option<&[Channel]> {
        self.joints
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, c)| c.as_slice())
    }
}

#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BvhReadOptions {
    /// Metres per file unit; `None` detects it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metres_per_unit: Option<f64>,
}

impl BvhReadOptions {
    pub fn is_default(&self) -> bool {
        self.metres_per_unit.is_none()
    }
}

/// Metres per unit of the CMU mocap BVH conversions (ASF `length 0.45`
/// inches): 0.0254 / 0.45.
pub const CMU_UNIT: f64 = 0.0254 / 0.45;

/// Guess metres per file unit from the summed bone lengths `s` (file units)
/// of a human skeleton (about 4.3 m for SMPL): 1.5–15 → metres, 15–150 → CMU
/// units, 150–1,500 → centimetres, 1,500–15,000 → millimetres. Inches are not
/// guessed (they overlap centimetres); pass the scale explicitly for them.
pub fn detect_unit(s: f64) -> Option<f64> {
    match s {
        s if (1.5..15.0).contains(&s) => Some(1.0),
        s if (15.0..150.0).contains(&s) => Some(CMU_UNIT),
        s if (150.0..1500.0).contains(&s) => Some(0.01),
        s if (1500.0..15000.0).contains(&s) => Some(0.001),
        _ => None,
    }
}

struct RawJoint {
    name: String,
    parent: Option<usize>,
    offset: Vec3,
    channels: Vec<Channel>,
    /// Index of this joint's first channel in a frame row.
    first: usize,
}

struct Tokens<'a> {
    file: &'a str,
    it: std::iter::Peekable<std::str::SplitWhitespace<'a>>,
}

impl<'a> Tokens<'a> {
    fn next(&mut self, what: &str) -> Result<&'a str, MotionError> {
        self.it.next().ok_or_else(|| {
            MotionError::invalid(self.file, what, "file ends early (truncated hierarchy)")
        })
    }
    fn expect(&mut self, want: &str) -> Result<(), MotionError> {
        let t = self.next(want)?;
        if t.eq_ignore_ascii_case(want) {
            Ok(())
        } else {
            Err(MotionError::invalid(
                self.file,
                want,
                format!("expected '{want}', found '{t}'"),
            ))
        }
    }
    fn num(&mut self, field: &str) -> Result<f64, MotionError> {
        let t = self.next(field)?;
        let v: f64 = t.parse().map_err(|_| {
            MotionError::invalid(self.file, field, format!("'{t}' is not a number"))
        })?;
        if !v.is_finite() {
            return Err(MotionError::invalid(
                self.file,
                field,
                format!("'{t}' is not finite"),
            ));
        }
        Ok(v)
    }
}

/// The result of reading a BVH file.
pub struct BvhMotion {
    pub motion: Motion,
    pub layout: BvhLayout,
}

pub fn read_bvh(file: &str, text: &str, opts: &BvhReadOptions) -> Result<BvhMotion, MotionError> {
    let mut tk = Tokens {
        file,
        it: text.split_whitespace().peekable(),
    };
    tk.expect("HIERARCHY")?;
    let mut joints: Vec<RawJoint> = Vec::new();
    let mut end_sites: Vec<EndSite> = Vec::new();
    // Stack of open blocks: Some(joint) or None for an End Site.
    let mut stack: Vec<Option<usize>> = Vec::new();
    let mut n_channels = 0usize;
    let first = tk.next("ROOT")?;
    if !first.eq_ignore_ascii_case("ROOT") {
        return Err(MotionError::invalid(
            file,
            "ROOT",
            format!("expected 'ROOT', found '{first}'"),
        ));
    }
    let mut pending: Option<(String, bool)> = Some((read_name(&mut tk)?, false));
    loop {
        if let Some((name, is_end)) = pending.take() {
            tk.expect("{")?;
            tk.expect("OFFSET")?;
            let offset = [tk.num("OFFSET")?, tk.num("OFFSET")?, tk.num("OFFSET")?];
            let parent = stack.last().copied().flatten();
            if is_end {
                let parent = parent
                    .ok_or_else(|| MotionError::invalid(file, "End Site", "outside any joint"))?;
                end_sites.push(EndSite { parent, offset });
                stack.push(None);
            } else {
                if joints.len() >= MAX_JOINTS {
                    return Err(MotionError::invalid(
                        file,
                        "JOINT",
                        format!("more than {MAX_JOINTS} joints"),
                    ));
                }
                if stack.last().is_some_and(|s| s.is_none()) {
                    return Err(MotionError::invalid(
                        file,
                        "JOINT",
                        format!("joint '{name}' inside an End Site"),
                    ));
                }
                let mut channels = Vec::new();
                if tk
                    .it
                    .peek()
                    .is_some_and(|t| t.eq_ignore_ascii_case("CHANNELS"))
                {
                    tk.next("CHANNELS")?;
                    let n = tk.num("CHANNELS")?;
                    if !(0.0..=6.0).contains(&n) || n.fract() != 0.0 {
                        return Err(MotionError::invalid(
                            file,
                            "CHANNELS",
                            format!("joint '{name}': {n} is not a channel count in 0..=6"),
                        ));
                    }
                    for _ in 0..n as usize {
                        let c = tk.next("CHANNELS")?;
                        channels.push(Channel::parse(c).ok_or_else(|| {
                            MotionError::invalid(
                                file,
                                "CHANNELS",
                                format!("joint '{name}': unknown channel '{c}'"),
                            )
                        })?);
                    }
                    let mut seen = std::collections::HashSet::new();
                    if !channels.iter().all(|c| seen.insert(*c)) {
                        return Err(MotionError::invalid(
                            file,
                            "CHANNELS",
                            format!("joint '{name}' repeats a channel"),
                        ));
                    }
                }
                if joints.iter().any(|j| j.name == name) {
                    return Err(MotionError::invalid(
                        file,
                        "JOINT",
                        format!("joint name '{name}' appears twice"),
                    ));
                }
                joints.push(RawJoint {
                    name,
                    parent,
                    offset,
                    first: n_channels,
                    channels,
                });
                n_channels += joints.last().map_or(0, |j| j.channels.len());
                stack.push(Some(joints.len() - 1));
            }
            if stack.len() > 256 {
                return Err(MotionError::invalid(
                    file,
                    "HIERARCHY",
                    "nesting deeper than 256",
                ));
            }
        }
        let t = tk.next("HIERARCHY")?;
        if t == "}" {
            stack
                .pop()
                .ok_or_else(|| MotionError::invalid(file, "HIERARCHY", "unbalanced '}'"))?;
            if stack.is_empty() {
                break;
            }
        } else if t.eq_ignore_ascii_case("JOINT") {
            pending = Some((read_name(&mut tk)?, false));
        } else if t.eq_ignore_ascii_case("End") {
            tk.expect("Site")?;
            pending = Some(("End Site".into(), true));
        } else {
            return Err(MotionError::invalid(
                file,
                "HIERARCHY",
                format!("unexpected token '{t}'"),
            ));
        }
    }
    // MOTION section.
    tk.expect("MOTION")?;
    let t = tk.next("Frames")?;
    let frames_f = if t.eq_ignore_ascii_case("Frames:") {
        tk.num("Frames")?
    } else if let Some(v) = t.strip_prefix("Frames:") {
        v.parse()
            .map_err(|_| MotionError::invalid(file, "Frames", format!("'{v}' is not a number")))?
    } else {
        return Err(MotionError::invalid(
            file,
            "Frames",
            format!("expected 'Frames:', found '{t}'"),
        ));
    };
    if !(frames_f >= 1.0 && frames_f <= MAX_FRAMES as f64 && frames_f.fract() == 0.0) {
        return Err(MotionError::invalid(
            file,
            "Frames",
            format!("{frames_f} is not a frame count in 1..={MAX_FRAMES}"),
        ));
    }
    let frames = frames_f as usize;
    tk.expect("Frame")?;
    tk.expect("Time:")?;
    let dt = tk.num("Frame Time")?;
    if !(dt > 0.0 && dt <= 10.0) {
        return Err(MotionError::invalid(
            file,
            "Frame Time",
            format!("{dt} s is not a frame time in (0, 10]"),
        ));
    }
    let expected = frames
        .checked_mul(n_channels)
        .ok_or_else(|| MotionError::invalid(file, "Frames", "frame count x channels overflows"))?;
    // Capacity bounded by what the text can hold (each value needs 2 bytes).
    let mut values = Vec::with_capacity(expected.min(text.len() / 2 + 1));
    for t in tk.it.by_ref() {
        if values.len() == expected {
            return Err(MotionError::invalid(
                file,
                "MOTION",
                format!("more values than {frames} frames x {n_channels} channels"),
            ));
        }
        let v: f64 = t.parse().map_err(|_| {
            MotionError::invalid(
                file,
                "MOTION",
                format!(
                    "frame {}: '{t}' is not a number",
                    values.len() / n_channels.max(1)
                ),
            )
        })?;
        if !v.is_finite() {
            return Err(MotionError::invalid(
                file,
                "MOTION",
                format!(
                    "frame {}: '{t}' is not finite",
                    values.len() / n_channels.max(1)
                ),
            ));
        }
        values.push(v);
    }
    if values.len() != expected {
        return Err(MotionError::invalid(
            file,
            "MOTION",
            format!(
                "truncated: {} values for {frames} frames x {n_channels} channels = {expected}",
                values.len()
            ),
        ));
    }
    let fps = 1.0 / dt;
    let fps = if (fps - fps.round()).abs() < 1e-4 * fps {
        fps.round()
    } else {
        fps
    };
    build_motion(file, joints, end_sites, &values, frames, fps, opts)
}

fn read_name(tk: &mut Tokens<'_>) -> Result<String, MotionError> {
    let mut parts = vec![tk.next("JOINT")?];
    while tk.it.peek().is_some_and(|t| *t != "{") {
        parts.push(tk.next("JOINT")?);
        if parts.len() > 16 {
            return Err(MotionError::invalid(
                tk.file,
                "JOINT",
                "joint name runs on without '{'",
            ));
        }
    }
    Ok(parts.join(" "))
}

/// A joint's per-frame local rotation and (if it has position channels) its
/// local translation, from a frame row.
fn local_transform(j: &RawJoint, row: &[f64]) -> (Quat, Option<Vec3>) {
    let mut q = IDENTITY_QUAT;
    let mut pos = j.offset;
    let mut has_pos = false;
    for (k, c) in j.channels.iter().enumerate() {
        let v = row[j.first + k];
        match c {
            Channel::Rot(a) => q = quat_mul(q, axis_quat(*a, v.to_radians())),
            Channel::Pos(a) => {
                pos[a.index()] = v;
                has_pos = true;
            }
        }
    }
    (quat_normalize(q), has_pos.then_some(pos))
}

fn build_motion(
    file: &str,
    mut joints: Vec<RawJoint>,
    mut end_sites: Vec<EndSite>,
    values: &[f64],
    frames: usize,
    fps: f64,
    opts: &BvhReadOptions,
) -> Result<BvhMotion, MotionError> {
    let nc = values.len() / frames;
    let row = |f: usize| &values[f * nc..(f + 1) * nc];
    // Fold a root whose only child carries its own translation (Bandai's
    // `joint_Root` → `Hips`): the child becomes the root, with the old root's
    // per-frame transform composed into it.
    let root_children: Vec<usize> = (1..joints.len())
        .filter(|&c| joints[c].parent == Some(0))
        .collect();
    let fold_root = root_children.len() == 1
        && !end_sites.iter().any(|e| e.parent == 0)
        && joints[root_children[0]]
            .channels
            .iter()
            .any(|c| matches!(c, Channel::Pos(_)));
    let root_fold: Option<Vec<(Quat, Vec3)>> = fold_root.then(|| {
        (0..frames)
            .map(|f| {
                let (q, p) = local_transform(&joints[0], row(f));
                (q, p.unwrap_or(joints[0].offset))
            })
            .collect()
    });
    let skip = usize::from(root_fold.is_some());
    if skip == 1 {
        joints.remove(0);
        for j in joints.iter_mut() {
            j.parent = j.parent.and_then(|p| p.checked_sub(1));
        }
        joints[0].parent = None;
        for e in end_sites.iter_mut() {
            e.parent -= 1;
        }
    }
    // Non-root translation channels must be constant.
    for j in joints.iter_mut().skip(1) {
        if !j.channels.iter().any(|c| matches!(c, Channel::Pos(_))) {
            continue;
        }
        let (_, p0) = local_transform(j, row(0));
        let p0 = p0.expect("has position channels");
        let mut range = 0.0f64;
        for f in 1..frames {
            let (_, p) = local_transform(j, row(f));
            range = range.max(norm(sub(p.expect("has position channels"), p0)));
        }
        if range > 1e-5 * (1.0 + norm(p0)) {
            return Err(MotionError::invalid(
                file,
                "CHANNELS",
                format!(
                    "joint '{}' translates over time (by up to {range:.4} units); only the root may move",
                    j.name
                ),
            ));
        }
        j.offset = p0;
    }
    // Units.
    let bone_sum: f64 = joints.iter().skip(1).map(|j| norm(j.offset)).sum();
    let unit = match opts.metres_per_unit {
        Some(u) if u.is_finite() && u > 0.0 => u,
        Some(u) => return Err(MotionError::invalid(file, "metres_per_unit", format!("{u} is not a positive scale"))),
        None => detect_unit(bone_sum).ok_or_else(|| {
            MotionError::invalid(
                file,
                "OFFSET",
                format!("cannot tell the unit from a bone-length sum of {bone_sum:.3}; give the scale explicitly"),
            )
        })?,
    };
    let names: Vec<String> = joints.iter().map(|j| j.name.clone()).collect();
    let parents: Vec<Option<usize>> = joints.iter().map(|j| j.parent).collect();
    let offsets: Vec<Vec3> = joints.iter().map(|j| scale(j.offset, unit)).collect();
    let end_sites: Vec<EndSite> = end_sites
        .into_iter()
        .map(|e| EndSite {
            parent: e.parent,
            offset: scale(e.offset, unit),
        })
        .collect();
    let skeleton =
        Skeleton::new("custom", names, parents, offsets, end_sites).map_err(|e| e.in_file(file))?;
    let nj = joints.len();
    let mut rotations = Vec::with_capacity(frames * nj);
    let mut trans = Vec::with_capacity(frames);
    for f in 0..frames {
        let r = row(f);
        for (k, j) in joints.iter().enumerate() {
            let (mut q, p) = local_transform(j, r);
            if k == 0 {
                let mut p = p.unwrap_or(j.offset);
                if let Some(fold) = &root_fold {
                    let (rq, rp) = fold[f];
                    q = quat_mul(rq, q);
                    p = add(rp, quat_rotate(rq, p));
                }
                trans.push(sub(scale(p, unit), skeleton.offsets[0]));
            }
            rotations.push(quat_to_axis_angle(q));
        }
    }
    let layout = BvhLayout {
        joints: joints
            .iter()
            .map(|j| (j.name.clone(), j.channels.clone()))
            .collect(),
        metres_per_unit: unit,
    };
    let mut l = labels::from_name(file);
    if l.is_empty() && file.contains("cmu") {
        l.insert("corpus".into(), "cmu".into());
    }
    let motion = Motion::new(file, fps, skeleton, trans, rotations, l)?;
    Ok(BvhMotion { motion, layout })
}

#[cfg(test)]
mod tests;
