//! The motion core: skeletons, rotations, clips and their operations, and the
//! readers/writers of the formats people have. Pure: no tokio, sqlx or tract.

pub mod clip;
pub mod contact;
pub mod foot_pin;
pub mod io;
pub mod keypoints;
pub mod labels;
pub mod retarget;
pub mod rotation;
pub mod skeleton;

pub use clip::{Labels, Motion};
pub use skeleton::Skeleton;

/// Every error of the motion core names the file (or the in-memory source),
/// the field and the reason.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    #[error("{file}: field `{field}`: {reason}")]
    Invalid {
        file: String,
        field: String,
        reason: String,
    },
    #[error("{file}: {reason}")]
    Unsupported { file: String, reason: String },
    /// The reason is in the message (not a chained source, which would
    /// print it twice).
    #[error("{file}: {error}")]
    Io { file: String, error: std::io::Error },
}

impl MotionError {
    pub fn invalid(
        file: impl Into<String>,
        field: impl Into<String>,
        reason: impl Into<String>,
    ) -> Self {
        MotionError::Invalid {
            file: file.into(),
            field: field.into(),
            reason: reason.into(),
        }
    }

    /// The same error re-labelled with a file name (for errors raised by pure
    /// code that only knew the motion's name).
    pub fn in_file(self, file: &str) -> Self {
        match self {
            MotionError::Invalid { field, reason, .. } => MotionError::Invalid {
                file: file.to_string(),
                field,
                reason,
            },
            MotionError::Unsupported { reason, .. } => MotionError::Unsupported {
                file: file.to_string(),
                reason,
            },
            MotionError::Io { error, .. } => MotionError::Io {
                file: file.to_string(),
                error,
            },
        }
    }
}
