//! choreo's JSON motion file format (`.json`): what `choreo convert`
//! writes and the store keeps inline motions in. The REST API's motion
//! (`api::http::MotionFile`) is its own type, so the wire contract does not
//! move when this format does. `rotations` is
//! `[frames][joints][3]` axis-angle (radians) on a named SMPL skeleton,
//! `translation` `[frames][3]` metres.

use crate::motion::{Labels, Motion, MotionError, Skeleton};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionFile {
    pub fps: f64,
    /// `smpl24` (the default) or `smpl13`.
    #[serde(default)]
    pub skeleton: String,
    pub rotations: Vec<Vec<[f64; 3]>>,
    pub translation: Vec<[f64; 3]>,
    #[serde(default)]
    pub labels: Labels,
    #[serde(default)]
    pub name: String,
}

/// A motion's rotations as `[frames][joints]` rows.
pub fn rotation_rows(m: &Motion) -> Vec<Vec<[f64; 3]>> {
    m.rotations
        .chunks(m.joints().max(1))
        .map(|c| c.to_vec())
        .collect()
}

/// `[frames][joints]` rows flattened frame by frame; a frame whose joint
/// count differs from frame 0's is refused with the reason.
pub fn flatten_rows(rows: Vec<Vec<[f64; 3]>>) -> Result<Vec<[f64; 3]>, String> {
    let joints = rows.first().map_or(0, |r| r.len());
    if let Some(f) = rows.iter().position(|r| r.len() != joints) {
        return Err(format!(
            "frame {f} has {} joints, frame 0 has {joints}",
            rows[f].len()
        ));
    }
    Ok(rows.into_iter().flatten().collect())
}

impl MotionFile {
    pub fn from_motion(m: &Motion) -> MotionFile {
        MotionFile {
            fps: m.fps,
            skeleton: m.skeleton.kind.clone(),
            rotations: rotation_rows(m),
            translation: m.trans.clone(),
            labels: m.labels.clone(),
            name: m.name.clone(),
        }
    }

    /// The motion, checked; errors name `file` and the field.
    pub fn into_motion(self, file: &str) -> Result<Motion, MotionError> {
        let rotations =
            flatten_rows(self.rotations).map_err(|r| MotionError::invalid(file, "rotations", r))?;
        let parts = MotionParts {
            name: self.name,
            fps: self.fps,
            skeleton: self.skeleton,
            rotations,
            translation: self.translation,
            labels: self.labels,
        };
        parts.into_motion(file)
    }
}

/// A motion as flat arrays (`rotations`: frames × joints × 3,
/// `translation`: frames × 3) on a named SMPL skeleton.
pub struct MotionParts {
    pub name: String,
    pub fps: f64,
    /// `smpl24` (also when empty) or `smpl13`.
    pub skeleton: String,
    pub rotations: Vec<[f64; 3]>,
    pub translation: Vec<[f64; 3]>,
    pub labels: Labels,
}

impl MotionParts {
    /// The motion, checked; errors name `file` (also the name when the
    /// parts have none) and the field.
    pub fn into_motion(self, file: &str) -> Result<Motion, MotionError> {
        let MotionParts {
            name,
            fps,
            skeleton,
            rotations,
            translation,
            labels,
        } = self;
        let sk = match skeleton.as_str() {
            "smpl24" | "" => Skeleton::smpl24(),
            "smpl13" => Skeleton::smpl13(),
            other => {
                return Err(MotionError::invalid(
                    file,
                    "skeleton",
                    format!(
                        "'{other}' is not smpl24 or smpl13 (send other skeletons as a BVH file)"
                    ),
                ))
            }
        };
        let frames = translation.len();
        if frames == 0 {
            return Err(MotionError::invalid(file, "translation", "no frames"));
        }
        if rotations.len() != frames * sk.len() {
            return Err(MotionError::invalid(
                file,
                "rotations",
                format!(
                    "{} rotations for {frames} frames × {} joints",
                    rotations.len(),
                    sk.len()
                ),
            ));
        }
        let name = if name.is_empty() { file } else { &name };
        Motion::new(name, fps, sk, translation, rotations, labels)
    }
}

/// Parse a JSON motion file.
pub fn read_json(file: &str, bytes: &[u8]) -> Result<Motion, MotionError> {
    let j: MotionFile = serde_json::from_slice(bytes)
        .map_err(|e| MotionError::invalid(file, "json", e.to_string()))?;
    j.into_motion(file)
}

/// Write a motion as JSON (exact: serde writes the shortest f64 that reads
/// back the same).
pub fn write_json(m: &Motion) -> Vec<u8> {
    serde_json::to_vec(&MotionFile::from_motion(m)).expect("a motion serialises")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_exact() {
        let m = crate::motion::clip::tests::sine_clip(30, 30.0);
        let back = read_json("x.json", &write_json(&m)).unwrap();
        assert_eq!(back.rotations, m.rotations);
        assert_eq!(back.trans, m.trans);
        assert_eq!(back.fps, m.fps);
        assert_eq!(back.skeleton.kind, m.skeleton.kind);
    }

    #[test]
    fn errors_name_the_field() {
        let e = read_json(
            "x.json",
            br#"{"fps":30,"rotations":[[[0,0,0]]],"translation":[]}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("x.json") && e.contains("translation"), "{e}");
        let e = read_json(
            "x.json",
            br#"{"fps":30,"skeleton":"horse","rotations":[],"translation":[[0,0,0]]}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("skeleton"), "{e}");
    }
}
