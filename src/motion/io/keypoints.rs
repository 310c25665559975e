//! Keypoint files from video pose estimators, read into
//! [`Keypoints`](crate::motion::keypoints::Keypoints) and written back (the
//! test data made from real takes).
//!
//! - `.npy` of shape `(T, K, 3)` (MotionBERT, VideoPose3D: Human3.6M-17,
//!   `K = 17`) or `(T, K, 4)` with a confidence in `[0, 1]` last. The file
//!   carries no frame rate, so one must be given. NaN rows are missed
//!   detections.
//! - choreo's keypoint JSON (MediaPipe has no file format of its own):
//!   `{"fps": F, "frames": [[[x, y, z, visibility] × K] per frame]}`, where
//!   a frame with no detection is `null` or `[]`, and a point may be
//!   `[x, y, z]` (visibility 1). `"layout"` may name the layout.
//!
//! Axes: both estimators write camera coordinates (x right, y down, z away
//! from the camera), so up is −y unless the reader is told otherwise.

use super::npy::{parse_npy, NdArray};
use crate::motion::clip::{MAX_FPS, MAX_FRAMES};
use crate::motion::keypoints::{Keypoints, Layout};
use crate::motion::MotionError;
use serde_json::Value;

/// The frame rate a file from video must be given; `what` says whose
/// (`keypoint files need`, …).
pub(crate) fn check_fps(file: &str, fps: Option<f64>, what: &str) -> Result<f64, MotionError> {
    let fps = fps.ok_or_else(|| {
        MotionError::invalid(
            file,
            "fps",
            format!("missing: {what} (--source-fps, API `fps`)"),
        )
    })?;
    if !(fps.is_finite() && fps > 0.0 && fps <= MAX_FPS) {
        return Err(MotionError::invalid(
            file,
            "fps",
            format!("{fps} is not in (0, {MAX_FPS}]"),
        ));
    }
    Ok(fps)
}

fn check_visibility(file: &str, field: &str, v: f64) -> Result<f64, MotionError> {
    if !(0.0..=1.0).contains(&v) {
        return Err(MotionError::invalid(
            file,
            field,
            format!("{v} is outside [0, 1]"),
        ));
    }
    Ok(v)
}

/// A `(T, K, 3|4)` `.npy` of the given layout.
pub fn read_npy(
    file: &str,
    bytes: &[u8],
    layout: Layout,
    fps: Option<f64>,
) -> Result<Keypoints, MotionError> {
    let a = parse_npy(bytes).map_err(|r| MotionError::invalid(file, "npy", r))?;
    let k = layout.len();
    let (t, c) = match a.shape.as_slice() {
        &[t, kk, c] if kk == k && (c == 3 || c == 4) => (t, c),
        s => {
            return Err(MotionError::invalid(
                file,
                "shape",
                format!("{s:?} is not (frames, {k}, 3) or (frames, {k}, 4) for {layout}"),
            ))
        }
    };
    if t == 0 || t > MAX_FRAMES {
        return Err(MotionError::invalid(
            file,
            "shape",
            format!("{t} frames is not in 1..={MAX_FRAMES}"),
        ));
    }
    let fps = check_fps(file, fps, "keypoint files need their frame rate")?;
    let mut points = Vec::with_capacity(t * k);
    let mut confidence = Vec::with_capacity(t * k);
    for (i, row) in a.data.chunks_exact(c).enumerate() {
        let p = [row[0], row[1], row[2]];
        let finite = p.iter().all(|v| v.is_finite());
        if !finite && !p.iter().all(|v| v.is_nan()) {
            return Err(MotionError::invalid(
                file,
                "keypoints",
                format!(
                    "frame {} point {} is {p:?}: only whole-NaN points (missed detections) may be non-finite",
                    i / k,
                    i % k
                ),
            ));
        }
        let conf = if c == 4 && finite {
            check_visibility(file, &format!("confidence[{}][{}]", i / k, i % k), row[3])?
        } else if finite {
            1.0
        } else {
            0.0
        };
        points.push(if finite { p } else { [f64::NAN; 3] });
        confidence.push(conf);
    }
    Ok(Keypoints {
        layout,
        fps,
        points,
        confidence,
    })
}

/// choreo's keypoint JSON. `fps` overrides the file's own.
pub fn read_json(
    file: &str,
    bytes: &[u8],
    layout: Layout,
    fps: Option<f64>,
) -> Result<Keypoints, MotionError> {
    let v: Value = serde_json::from_slice(bytes)
        .map_err(|e| MotionError::invalid(file, "json", e.to_string()))?;
    let o = v
        .as_object()
        .ok_or_else(|| MotionError::invalid(file, "json", "top level is not an object"))?;
    for key in o.keys() {
        if !matches!(key.as_str(), "fps" | "frames" | "layout") {
            return Err(MotionError::invalid(
                file,
                key,
                "unknown field (expected fps, frames, layout)",
            ));
        }
    }
    if let Some(l) = o.get("layout") {
        let named: Layout = l
            .as_str()
            .ok_or_else(|| MotionError::invalid(file, "layout", "is not a string"))?
            .parse()
            .map_err(|e: String| MotionError::invalid(file, "layout", e))?;
        if named != layout {
            return Err(MotionError::invalid(
                file,
                "layout",
                format!("the file says {named}, the reader was told {layout}"),
            ));
        }
    }
    let file_fps = match o.get("fps") {
        None | Some(Value::Null) => None,
        Some(x) => Some(
            x.as_f64()
                .ok_or_else(|| MotionError::invalid(file, "fps", "is not a number"))?,
        ),
    };
    let fps = check_fps(
        file,
        fps.or(file_fps),
        "keypoint files need their frame rate",
    )?;
    let frames = o
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| MotionError::invalid(file, "frames", "missing or not an array"))?;
    if frames.is_empty() || frames.len() > MAX_FRAMES {
        return Err(MotionError::invalid(
            file,
            "frames",
            format!("{} frames is not in 1..={MAX_FRAMES}", frames.len()),
        ));
    }
    let k = layout.len();
    let mut points = Vec::with_capacity(frames.len() * k);
    let mut confidence = Vec::with_capacity(frames.len() * k);
    for (f, fr) in frames.iter().enumerate() {
        let pts = match fr {
            Value::Null => None,
            Value::Array(a) if a.is_empty() => None,
            Value::Array(a) if a.len() == k => Some(a),
            _ => {
                return Err(MotionError::invalid(
                    file,
                    format!("frames[{f}]"),
                    format!("must be null, [] or {k} points ({layout})"),
                ))
            }
        };
        let Some(pts) = pts else {
            points.extend(std::iter::repeat_n([f64::NAN; 3], k));
            confidence.extend(std::iter::repeat_n(0.0, k));
            continue;
        };
        for (i, p) in pts.iter().enumerate() {
            let field = || format!("frames[{f}][{i}]");
            let a = p
                .as_array()
                .filter(|a| a.len() == 3 || a.len() == 4)
                .ok_or_else(|| {
                    MotionError::invalid(file, field(), "is not [x, y, z, visibility]")
                })?;
            let mut xs = [0.0; 4];
            xs[3] = 1.0;
            for (d, x) in a.iter().enumerate() {
                xs[d] = x
                    .as_f64()
                    .ok_or_else(|| MotionError::invalid(file, field(), "holds a non-number"))?;
            }
            check_visibility(file, &format!("{}[3]", field()), xs[3])?;
            points.push([xs[0], xs[1], xs[2]]);
            confidence.push(xs[3]);
        }
    }
    Ok(Keypoints {
        layout,
        fps,
        points,
        confidence,
    })
}

/// `(T, K, 3)` f32, NaN where missed (the MotionBERT shape).
pub fn write_npy(kp: &Keypoints) -> Vec<u8> {
    let k = kp.layout.len();
    NdArray {
        shape: vec![kp.frames(), k, 3],
        data: kp.points.iter().flatten().copied().collect(),
    }
    .to_npy(true)
}

/// choreo's keypoint JSON; a frame whose points are all missing is `null`.
pub fn write_json(kp: &Keypoints) -> Vec<u8> {
    let k = kp.layout.len();
    let round = |v: f64| (v * 1e5).round() / 1e5;
    let frames: Vec<Value> = (0..kp.frames())
        .map(|f| {
            let pts = &kp.points[f * k..(f + 1) * k];
            if pts.iter().all(|p| p[0].is_nan()) {
                return Value::Null;
            }
            Value::Array(
                pts.iter()
                    .zip(&kp.confidence[f * k..(f + 1) * k])
                    .map(|(p, c)| {
                        serde_json::json!([round(p[0]), round(p[1]), round(p[2]), round(*c)])
                    })
                    .collect(),
            )
        })
        .collect();
    serde_json::to_vec(&serde_json::json!({
        "layout": kp.layout.name(),
        "fps": kp.fps,
        "frames": frames,
    }))
    .expect("keypoint JSON serialises")
}
