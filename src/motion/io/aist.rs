//! The official AIST++ motion annotation pickle: a dict with `smpl_poses`
//! `(N, 72)` axis-angle, `smpl_trans` `(N, 3)`, `smpl_scaling` `(1,)`, at 60 fps.
//! Metres are `smpl_trans / smpl_scaling`, y up.

use super::pickle::{self, dict_get, Value};
use crate::motion::clip::{Labels, Motion, MAX_FRAMES};
use crate::motion::labels;
use crate::motion::skeleton::Skeleton;
use crate::motion::MotionError;

/// AIST++ motions are captured at 60 fps.
pub const AIST_FPS: f64 = 60.0;

fn array<'a>(
    file: &str,
    d: &'a [(Value, Value)],
    key: &str,
) -> Result<&'a super::npy::NdArray, MotionError> {
    match dict_get(d, key) {
        Some(Value::Array(a)) => Ok(a),
        Some(_) => Err(MotionError::invalid(file, key, "is not a numpy array")),
        None => Err(MotionError::invalid(file, key, "missing from the pickle")),
    }
}

/// Parse an AIST++ pickle's bytes; `file` names it in errors and labels.
pub fn read_aist_pickle(file: &str, bytes: &[u8]) -> Result<Motion, MotionError> {
    let root = pickle::load(bytes).map_err(|r| MotionError::invalid(file, "pickle", r))?;
    read_aist_value(file, &root)
}

/// An AIST++ motion from a parsed pickle.
pub fn read_aist_value(file: &str, root: &Value) -> Result<Motion, MotionError> {
    let d = root
        .as_dict()
        .ok_or_else(|| MotionError::invalid(file, "pickle", "top-level object is not a dict"))?;
    let poses = array(file, d, "smpl_poses")?;
    let trans = array(file, d, "smpl_trans")?;
    let (n, w) = poses.dims2().ok_or_else(|| {
        MotionError::invalid(
            file,
            "smpl_poses",
            format!("shape {:?} is not 2-D", poses.shape),
        )
    })?;
    if w != 72 {
        return Err(MotionError::invalid(
            file,
            "smpl_poses",
            format!("has {w} columns, expected 72 (24 joints x 3)"),
        ));
    }
    if n == 0 || n > MAX_FRAMES {
        return Err(MotionError::invalid(
            file,
            "smpl_poses",
            format!("{n} frames is not in 1..={MAX_FRAMES}"),
        ));
    }
    if trans.dims2() != Some((n, 3)) {
        return Err(MotionError::invalid(
            file,
            "smpl_trans",
            format!("shape {:?} does not match {n} frames x 3", trans.shape),
        ));
    }
    let scaling = match dict_get(d, "smpl_scaling") {
        Some(Value::Array(a)) => a.scalar().ok_or_else(|| {
            MotionError::invalid(
                file,
                "smpl_scaling",
                format!("shape {:?} is not one value", a.shape),
            )
        })?,
        Some(Value::Float(f)) => *f,
        Some(Value::Int(i)) => *i as f64,
        Some(_) => {
            return Err(MotionError::invalid(
                file,
                "smpl_scaling",
                "is not a number",
            ))
        }
        None => {
            return Err(MotionError::invalid(
                file,
                "smpl_scaling",
                "missing from the pickle",
            ))
        }
    };
    if !(scaling.is_finite() && scaling > 0.0) {
        return Err(MotionError::invalid(
            file,
            "smpl_scaling",
            format!("{scaling} is not a positive scale"),
        ));
    }
    if let Some(i) = poses.data.iter().position(|v| !v.is_finite()) {
        return Err(MotionError::invalid(
            file,
            "smpl_poses",
            format!("frame {} value {} is {}", i / 72, i % 72, poses.data[i]),
        ));
    }
    if let Some(i) = trans.data.iter().position(|v| !v.is_finite()) {
        return Err(MotionError::invalid(
            file,
            "smpl_trans",
            format!("frame {} is {}", i / 3, trans.data[i]),
        ));
    }
    let rotations = poses
        .data
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let trans = trans
        .data
        .chunks_exact(3)
        .map(|c| [c[0] / scaling, c[1] / scaling, c[2] / scaling])
        .collect();
    let mut l: Labels = labels::from_name(file);
    l.entry("corpus".into()).or_insert_with(|| "aistpp".into());
    Motion::new(file, AIST_FPS, Skeleton::smpl24(), trans, rotations, l)
}
