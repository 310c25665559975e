//! The REST API's motion: `rotations` `[frames][joints][3]` axis-angle
//! (radians) on a named SMPL skeleton, `translation` `[frames][3]` metres.
//! The wire type of every inline motion in a request (`"motion":
//! {"motion": …}`), a duet frame, and every motion in a response.

use crate::motion::io::json::{flatten_rows, rotation_rows, MotionParts};
use crate::motion::{Labels, Motion};
use crate::service::ApiError;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionJson {
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

impl MotionJson {
    pub fn from_motion(m: &Motion) -> MotionJson {
        MotionJson {
            fps: m.fps,
            skeleton: m.skeleton.kind.clone(),
            rotations: rotation_rows(m),
            translation: m.trans.clone(),
            labels: m.labels.clone(),
            name: m.name.clone(),
        }
    }

    /// The transport-neutral parts (as gRPC gives them); a frame with
    /// another joint count than frame 0 is refused as `field.rotations`.
    pub fn into_parts(self, field: &str) -> Result<MotionParts, ApiError> {
        let rotations = flatten_rows(self.rotations)
            .map_err(|r| ApiError::invalid(format!("{field}.rotations"), r))?;
        Ok(MotionParts {
            name: self.name,
            fps: self.fps,
            skeleton: self.skeleton,
            rotations,
            translation: self.translation,
            labels: self.labels,
        })
    }
}
