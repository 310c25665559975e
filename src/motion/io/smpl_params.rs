//! SMPL parameters from video estimators (WHAM-style `.npz` or a plain
//! `.pkl` dict): rotations are estimated already, so no inverse kinematics.
//!
//! Arrays read (first found wins):
//! - `pose_world` `(T, 72)` with `trans_world` `(T, 3)`: WHAM's world output,
//!   y up;
//! - else `pose` `(T, 72)`, or `global_orient` `(T, 3)` with `body_pose`
//!   `(T, 69)` (SMPL, 23 joints) or `(T, 63)` (SMPL-X/H body, 21 joints;
//!   the palms stay at rest), with `trans` `(T, 3)` (zeros if absent): the
//!   camera frame, y down. Each may also be `(T, J, 3)` axis-angle or
//!   `(T, J, 3, 3)` rotation matrices.
//! - `frame_ids` `(T,)`: the video frames the person was detected in. The
//!   motion spans the first to the last; frames in between that were not
//!   detected are flagged and bridged by SLERP, as are rows with NaN.
//! - `betas` is read past: choreo's skeleton is SMPL's neutral body.
//!
//! A pickle may hold one person's dict, or a dict of people (WHAM's
//! `{id: {...}}`), of which the longest track is read. Such files carry no
//! frame rate; it must be given.

use super::npy::NdArray;
use super::pickle::{self, dict_get, Value};
use crate::motion::clip::{Labels, Motion, MAX_FRAMES};
use crate::motion::keypoints::{bridge, FootageReport, Up};
use crate::motion::labels;
use crate::motion::rotation::*;
use crate::motion::skeleton::Skeleton;
use crate::motion::MotionError;

/// The keys that make an `.npz` or a pickle dict SMPL parameters.
pub const POSE_KEYS: [&str; 3] = ["pose_world", "pose", "body_pose"];

/// Whether a pickle dict (or a dict of them) holds SMPL parameters.
pub fn is_smpl_params(v: &Value) -> bool {
    let has = |d: &[(Value, Value)]| POSE_KEYS.iter().any(|k| dict_get(d, k).is_some());
    match v.as_dict() {
        Some(d) if has(d) => true,
        Some(d) => d.iter().any(|(_, p)| p.as_dict().is_some_and(has)),
        None => false,
    }
}

/// Rotations `[T][joints]` from an array of axis-angles or matrices.
fn rotations(
    file: &str,
    key: &str,
    a: &NdArray,
    joints: &[usize],
) -> Result<(usize, usize, Vec<Vec3>), MotionError> {
    let bad = || {
        MotionError::invalid(
            file,
            key,
            format!("shape {:?} is not (frames, J·3), (frames, J, 3) or (frames, J, 3, 3) with J in {joints:?}", a.shape),
        )
    };
    let (t, j, mats) = match a.shape.as_slice() {
        &[t, w] if w % 3 == 0 && joints.contains(&(w / 3)) => (t, w / 3, false),
        &[t, j, 3] if joints.contains(&j) => (t, j, false),
        &[t, j, 3, 3] if joints.contains(&j) => (t, j, true),
        _ => return Err(bad()),
    };
    let out = if mats {
        a.data
            .chunks_exact(9)
            .map(|m| {
                if m.iter().all(|v| v.is_finite()) {
                    mat_to_axis_angle(&[[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]])
                } else {
                    [f64::NAN; 3]
                }
            })
            .collect()
    } else {
        a.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    };
    Ok((t, j, out))
}

/// Build the motion from the arrays `get` finds.
fn build(
    file: &str,
    get: &dyn Fn(&str) -> Option<NdArray>,
    fps: Option<f64>,
    up: Option<Up>,
) -> Result<(Motion, FootageReport), MotionError> {
    let fps = super::keypoints::check_fps(
        file,
        fps,
        "SMPL parameters from video carry no frame rate; give one",
    )?;
    // (frames, rotations [T][24], trans key, default up)
    let (t, rots, trans_key, default_up) = if let Some(p) = get("pose_world") {
        let (t, _, r) = rotations(file, "pose_world", &p, &[24])?;
        (t, r, "trans_world", Up::Y)
    } else if let Some(p) = get("pose") {
        let (t, _, r) = rotations(file, "pose", &p, &[24])?;
        (t, r, "trans", Up::NegY)
    } else if let Some(b) = get("body_pose") {
        let (t, j, body) = rotations(file, "body_pose", &b, &[21, 23])?;
        let g = get("global_orient").ok_or_else(|| {
            MotionError::invalid(file, "global_orient", "missing beside body_pose")
        })?;
        let (tg, _, root) = rotations(file, "global_orient", &g, &[1])?;
        if tg != t {
            return Err(MotionError::invalid(
                file,
                "global_orient",
                format!("{tg} frames, body_pose has {t}"),
            ));
        }
        let mut r = vec![[0.0; 3]; t * 24];
        for f in 0..t {
            r[f * 24] = root[f];
            for k in 0..j {
                r[f * 24 + 1 + k] = body[f * j + k];
            }
        }
        (t, r, "trans", Up::NegY)
    } else {
        return Err(MotionError::invalid(
            file,
            "pose",
            "no pose_world, pose or global_orient + body_pose array",
        ));
    };
    if t == 0 || t > MAX_FRAMES {
        return Err(MotionError::invalid(
            file,
            "pose",
            format!("{t} frames is not in 1..={MAX_FRAMES}"),
        ));
    }
    let trans: Vec<Vec3> = match get(trans_key) {
        Some(a) => {
            if a.data.len() != t * 3 {
                return Err(MotionError::invalid(
                    file,
                    trans_key,
                    format!("shape {:?} does not match {t} frames x 3", a.shape),
                ));
            }
            a.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
        }
        None => vec![[0.0; 3]; t],
    };
    // Where each row lands in the output: frame_ids relative to the first.
    let (first, slots) = match get("frame_ids") {
        Some(ids) => {
            if ids.data.len() != t {
                return Err(MotionError::invalid(
                    file,
                    "frame_ids",
                    format!("{} ids for {t} frames", ids.data.len()),
                ));
            }
            let mut slots = Vec::with_capacity(t);
            for (i, &v) in ids.data.iter().enumerate() {
                if !(v.is_finite() && v >= 0.0 && v.fract() == 0.0) {
                    return Err(MotionError::invalid(
                        file,
                        "frame_ids",
                        format!("[{i}] = {v} is not a frame number"),
                    ));
                }
                if i > 0 && v <= ids.data[i - 1] {
                    return Err(MotionError::invalid(
                        file,
                        "frame_ids",
                        format!("[{i}] = {v} does not increase"),
                    ));
                }
                slots.push((v - ids.data[0]) as usize);
            }
            if slots[t - 1] >= MAX_FRAMES || slots[t - 1] + 1 > 2 * t + 1000 {
                return Err(MotionError::invalid(
                    file,
                    "frame_ids",
                    format!(
                        "span {} frames for {t} detections: too sparse to bridge",
                        slots[t - 1] + 1
                    ),
                ));
            }
            (ids.data[0] as usize, slots)
        }
        None => (0, (0..t).collect()),
    };
    let frames = slots[t - 1] + 1;
    let up = up.unwrap_or(default_up);
    let turn = up.to_y_up();
    let o0 = Skeleton::smpl24().offsets[0];
    let mut good = vec![false; frames];
    let mut out_rots = vec![[0.0; 3]; frames * 24];
    let mut out_trans = vec![[0.0; 3]; frames];
    for (row, &slot) in slots.iter().enumerate() {
        let r = &rots[row * 24..(row + 1) * 24];
        if !(r.iter().flatten().all(|v| v.is_finite()) && trans[row].iter().all(|v| v.is_finite()))
        {
            continue;
        }
        good[slot] = true;
        out_rots[slot * 24..(slot + 1) * 24].copy_from_slice(r);
        out_rots[slot * 24] = quat_to_axis_angle(quat_mul(turn, axis_angle_to_quat(r[0])));
        // The pelvis sits at o0 + trans in the source frame; it turns with it.
        out_trans[slot] = sub(quat_rotate(turn, add(o0, trans[row])), o0);
    }
    let n_good = good.iter().filter(|g| **g).count();
    if n_good == 0
        || (frames - n_good) as f64 > crate::motion::keypoints::MAX_MISSING_SHARE * frames as f64
    {
        return Err(MotionError::invalid(
            file,
            "pose",
            format!(
                "{} of {frames} frames are missing or NaN; at most half may be",
                frames - n_good
            ),
        ));
    }
    let gaps = bridge(&good, &mut out_rots, &mut out_trans);
    let mut l: Labels = labels::from_name(file);
    l.entry("corpus".into()).or_insert_with(|| "video".into());
    let m = Motion::new(file, fps, Skeleton::smpl24(), out_trans, out_rots, l)?;
    Ok((
        m,
        FootageReport {
            layout: "smpl".into(),
            frames,
            flagged_frames: frames - n_good,
            gaps,
            metres_per_unit: 1.0,
            mean_confidence: 1.0,
            confidence: good.iter().map(|g| if *g { 1.0 } else { 0.0 }).collect(),
            up: up.name().into(),
            min_confidence: 0.0,
            smooth_s: 0.0,
            first_frame: first,
        },
    ))
}

/// An `.npz` of SMPL parameters.
pub fn read_npz(
    file: &str,
    bytes: &[u8],
    fps: Option<f64>,
    up: Option<Up>,
) -> Result<(Motion, FootageReport), MotionError> {
    let zip = std::cell::RefCell::new(zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(
        |e| MotionError::invalid(file, "npz", format!("not a readable zip archive: {e}")),
    )?);
    let err = std::cell::RefCell::new(None);
    let get = |key: &str| match super::amass::entry(file, &mut zip.borrow_mut(), &[key]) {
        Ok(a) => a,
        Err(e) => {
            err.borrow_mut().get_or_insert(e);
            None
        }
    };
    let out = build(file, &get, fps, up);
    match err.into_inner() {
        Some(e) => Err(e),
        None => out,
    }
}

/// A pickle's SMPL parameters (one person's dict, or the longest of a dict
/// of people).
pub fn read_pickle_value(
    file: &str,
    v: &Value,
    fps: Option<f64>,
    up: Option<Up>,
) -> Result<(Motion, FootageReport), MotionError> {
    let d = v
        .as_dict()
        .ok_or_else(|| MotionError::invalid(file, "pickle", "top-level object is not a dict"))?;
    let has = |d: &[(Value, Value)]| POSE_KEYS.iter().any(|k| dict_get(d, k).is_some());
    let person: &[(Value, Value)] = if has(d) {
        d
    } else {
        let frames = |p: &[(Value, Value)]| {
            POSE_KEYS
                .iter()
                .find_map(|k| match dict_get(p, k) {
                    Some(Value::Array(a)) => a.shape.first().copied(),
                    _ => None,
                })
                .unwrap_or(0)
        };
        d.iter()
            .filter_map(|(_, p)| p.as_dict().filter(|p| has(p)))
            .max_by_key(|p| frames(p))
            .ok_or_else(|| {
                MotionError::invalid(
                    file,
                    "pose",
                    "no person's dict holds pose_world, pose or body_pose",
                )
            })?
    };
    let err = std::cell::RefCell::new(None);
    let get = |key: &str| match dict_get(person, key) {
        Some(Value::Array(a)) => Some(a.clone()),
        Some(Value::Int(i)) => Some(NdArray {
            shape: vec![],
            data: vec![*i as f64],
        }),
        Some(_) => {
            err.borrow_mut()
                .get_or_insert(MotionError::invalid(file, key, "is not a numpy array"));
            None
        }
        None => None,
    };
    let out = build(file, &get, fps, up);
    match err.into_inner() {
        Some(e) => Err(e),
        None => out,
    }
}

/// Parse a pickle for [`read_pickle_value`].
pub fn load_pickle(file: &str, bytes: &[u8]) -> Result<Value, MotionError> {
    pickle::load(bytes).map_err(|r| MotionError::invalid(file, "pickle", r))
}

/// An SMPL-24 motion as a WHAM-style `.npz` (`pose_world`, `trans_world`,
/// `betas` zeros, `frame_ids`), keeping only the rows in `keep` (the frames
/// "detected").
pub fn write_npz(m: &Motion, keep: &[usize]) -> Result<Vec<u8>, MotionError> {
    if m.skeleton.kind != "smpl24" {
        return Err(MotionError::invalid(
            &m.name,
            "skeleton",
            "SMPL parameters need an SMPL-24 motion",
        ));
    }
    let n = keep.len();
    let mut pose = Vec::with_capacity(n * 72);
    let mut trans = Vec::with_capacity(n * 3);
    for &f in keep {
        pose.extend(m.frame_rotations(f).iter().flatten());
        trans.extend(m.trans[f]);
    }
    super::amass::write_npz(
        &m.name,
        &[
            (
                "pose_world.npy",
                NdArray {
                    shape: vec![n, 72],
                    data: pose,
                },
            ),
            (
                "trans_world.npy",
                NdArray {
                    shape: vec![n, 3],
                    data: trans,
                },
            ),
            (
                "betas.npy",
                NdArray {
                    shape: vec![n, 10],
                    data: vec![0.0; n * 10],
                },
            ),
            (
                "frame_ids.npy",
                NdArray {
                    shape: vec![n],
                    data: keep.iter().map(|&f| f as f64).collect(),
                },
            ),
        ],
    )
}
