//! Classify: the dancer / genre / situation (content / style) of a clip by
//! the language model's class heads.

use super::generate::model;
use super::input::MotionInput;
use super::{auth, ApiError, Choreo};

/// Windows a classification reads at most (spread over the clip).
pub const MAX_CLASSIFY_WINDOWS: usize = 32;

/// Class probabilities per label kind the model classifies.
pub type Classes = Vec<(String, Vec<(String, f64)>)>;

pub async fn classify(
    state: &Choreo,
    motion: MotionInput,
    who: &auth::Principal,
) -> Result<Classes, ApiError> {
    let session = model(state)?;
    let m = state.resolve("motion", motion, who).await?;
    state
        .heavy("classify", move || {
            let tokens = session.vocabulary().encode_motion(&m)?;
            Ok(session.classify(&tokens, MAX_CLASSIFY_WINDOWS)?)
        })
        .await
}
