//! Low-pass filtering of a motion's rotation channels (SPEC §3).

use super::input::{prefix, MotionInput};
use super::interpolate::with_channels;
use super::{auth, ApiError, Choreo};
use crate::features::interpolate::{lowpass as lowpass_channels, to_f64};
use crate::features::{rows72, smpl24_at_60};
use crate::motion::Motion;

pub async fn lowpass(
    state: &Choreo,
    motion: MotionInput,
    cutoff: usize,
    who: &auth::Principal,
) -> Result<Motion, ApiError> {
    let m = state.resolve("motion", motion, who).await?;
    state
        .heavy("lowpass", move || {
            let m = smpl24_at_60(&m)?;
            let out = lowpass_channels(&to_f64(&rows72(&m)), cutoff)
                .map_err(|e| prefix("cutoff", e.into()))?;
            Ok(with_channels(&m, &out))
        })
        .await
}
