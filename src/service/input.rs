//! Where a request's motion comes from (inline, an upload, a stored id),
//! and resolving it into a [`Motion`] with the request's own field names in
//! every error.

use super::{auth, ApiError, Choreo};
use crate::motion::io::json::MotionParts;
use crate::motion::io::{read_bytes, ReadOptions};
use crate::motion::Motion;
use crate::search::ingest::load_motion;

/// Longest motion accepted in a request, in seconds (inline or uploaded;
/// the body-size limit bounds the frame count as well).
pub const MAX_SECONDS: f64 = 600.0;

/// Where a request's motion comes from.
pub enum MotionInput {
    Inline(Motion),
    File {
        name: String,
        bytes: Vec<u8>,
        /// How to read it (keypoint layout, frame rate, up axis).
        read: ReadOptions,
    },
    /// A stored motion, by id.
    Stored(i64),
}

/// The motion of inline parts; errors name `field.<part>`.
pub fn motion_from_parts(field: &str, mut parts: MotionParts) -> Result<Motion, ApiError> {
    if parts.name.is_empty() {
        parts.name = "request".into();
    }
    let name = parts.name.clone();
    parts
        .into_motion(&name)
        .map_err(|e| prefix(field, e.into()))
}

pub(crate) fn prefix(field: &str, e: ApiError) -> ApiError {
    match e {
        ApiError::Invalid { field: f, reason } => ApiError::Invalid {
            field: format!("{field}.{f}"),
            reason,
        },
        other => other,
    }
}

fn check_duration(field: &str, m: &Motion) -> Result<(), ApiError> {
    if m.duration_s() > MAX_SECONDS {
        return Err(ApiError::invalid(
            format!("{field}.frames"),
            format!("{:.1} s is over the {MAX_SECONDS} s limit", m.duration_s()),
        ));
    }
    Ok(())
}

impl Choreo {
    /// The motion of any input (uploads parsed, stored ones read from the
    /// store), checked against the duration limit.
    pub async fn resolve(
        &self,
        field: &str,
        input: MotionInput,
        who: &auth::Principal,
    ) -> Result<Motion, ApiError> {
        let m = match input {
            MotionInput::Inline(m) => m,
            MotionInput::File { name, bytes, read } => {
                if name.is_empty() {
                    return Err(ApiError::invalid(
                        format!("{field}.file.name"),
                        "an upload needs its file name (the extension gives the format)",
                    ));
                }
                // Parsing (pickle, npz, BVH, keypoints with their
                // smoothing) is CPU work: the blocking pool, not a worker
                // of the async runtime.
                tokio::task::spawn_blocking(move || read_bytes(&name, &bytes, &read))
                    .await
                    .map_err(|e| ApiError::Internal(format!("{field}: reading failed: {e}")))?
                    .map_err(|e| prefix(field, e.into()))?
                    .motion
            }
            MotionInput::Stored(id) => {
                load_motion(&self.store, id)
                    .await
                    .map_err(|e| prefix(field, e.into()))?
                    // A motion of a collection the caller cannot see is
                    // answered as if it did not exist.
                    .filter(|(row, _)| who.sees(&row.collection))
                    .ok_or_else(|| ApiError::Missing {
                        field: format!("{field}.id"),
                        reason: format!("no stored motion {id}"),
                    })?
                    .1
            }
        };
        check_duration(field, &m)?;
        Ok(m)
    }
}

/// Reader options from a request's file source (`field` prefixes the
/// names in errors): a keypoint layout, frame rate, up axis and confidence
/// threshold, each optional.
pub fn read_options(
    field: &str,
    keypoints: Option<&str>,
    fps: Option<f64>,
    up: Option<&str>,
    min_confidence: Option<f64>,
    smooth_s: Option<f64>,
) -> Result<ReadOptions, ApiError> {
    let keypoints = keypoints
        .map(|k| {
            k.parse()
                .map_err(|e: String| ApiError::invalid(format!("{field}.keypoints"), e))
        })
        .transpose()?;
    let up = up
        .map(|u| {
            u.parse()
                .map_err(|e: String| ApiError::invalid(format!("{field}.up"), e))
        })
        .transpose()?;
    if let Some(f) = fps {
        if !(f.is_finite() && f > 0.0 && f <= crate::motion::clip::MAX_FPS) {
            return Err(ApiError::invalid(
                format!("{field}.fps"),
                format!("{f} is not a frame rate"),
            ));
        }
    }
    if let Some(c) = min_confidence {
        if !(0.0..=1.0).contains(&c) {
            return Err(ApiError::invalid(
                format!("{field}.min_confidence"),
                format!("{c} is not in [0, 1]"),
            ));
        }
    }
    if let Some(v) = smooth_s {
        if !(0.0..=1.0).contains(&v) {
            return Err(ApiError::invalid(
                format!("{field}.smooth_s"),
                format!("{v} is not in [0, 1] seconds"),
            ));
        }
    }
    Ok(ReadOptions {
        keypoints,
        fps,
        up,
        min_confidence,
        smooth_s,
        ..Default::default()
    })
}
