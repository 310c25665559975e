//! The service's transport-neutral layer: requests and responses as domain
//! types, the operations both transports call, and the one error
//! vocabulary with its two translations (HTTP status, gRPC code).
//!
//! [`http`] (axum) and [`grpc`] (tonic) only convert wire types to the
//! requests here and back (ARCHITECTURE rule 1).

pub mod grpc;
pub mod http;
pub mod lm;
pub mod metrics;

use crate::features::interpolate::{lowpass as lowpass_channels, to_f64, InterpolateOptions};
use crate::features::{rows72, smpl24_at_60, Embedding};
use crate::index::Metric;
use crate::motion::io::{read_bytes, ReadOptions};
use crate::motion::{Labels, Motion, MotionError, Skeleton};
use crate::service::interpolate::{interpolate_motions, with_channels, InterpolateReport};
use crate::service::keyframes::{
    reconstruct, Inbetween, KeyframeReport, KeyframeRequest, Music, Select,
};
use crate::service::query::{QueryError, QueryHit, QueryRequest, Searcher};
use crate::store::{MotionRow, Store};
use std::sync::Arc;
use tokio::sync::Semaphore;

/// Longest motion accepted in a request, in seconds (inline or uploaded;
/// the body-size limit bounds the frame count as well).
pub const MAX_SECONDS: f64 = 600.0;

/// Errors every endpoint can answer with.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The request is wrong: names the field and why.
    #[error("{field}: {reason}")]
    Invalid { field: String, reason: String },
    #[error("not found: {0}")]
    NotFound(String),
    /// Every worker permit is taken: try again later.
    #[error("busy: {0}")]
    Busy(String),
    /// The capability is not loaded (no model).
    #[error("unavailable: {0}")]
    Unavailable(String),
    #[error("internal error: {0}")]
    Internal(String),
}

impl ApiError {
    pub fn invalid(field: impl Into<String>, reason: impl Into<String>) -> ApiError {
        ApiError::Invalid {
            field: field.into(),
            reason: reason.into(),
        }
    }
    /// The HTTP translation.
    pub fn http_status(&self) -> u16 {
        match self {
            ApiError::Invalid { .. } => 400,
            ApiError::NotFound(_) => 404,
            ApiError::Busy(_) => 429,
            ApiError::Unavailable(_) => 503,
            ApiError::Internal(_) => 500,
        }
    }
    /// The gRPC translation.
    pub fn grpc_code(&self) -> tonic::Code {
        match self {
            ApiError::Invalid { .. } => tonic::Code::InvalidArgument,
            ApiError::NotFound(_) => tonic::Code::NotFound,
            ApiError::Busy(_) => tonic::Code::ResourceExhausted,
            ApiError::Unavailable(_) => tonic::Code::Unavailable,
            ApiError::Internal(_) => tonic::Code::Internal,
        }
    }
    pub fn kind(&self) -> &'static str {
        match self {
            ApiError::Invalid { .. } => "invalid_argument",
            ApiError::NotFound(_) => "not_found",
            ApiError::Busy(_) => "resource_exhausted",
            ApiError::Unavailable(_) => "unavailable",
            ApiError::Internal(_) => "internal",
        }
    }
}

impl From<MotionError> for ApiError {
    fn from(e: MotionError) -> Self {
        match e {
            MotionError::Invalid {
                file,
                field,
                reason,
            } => ApiError::Invalid {
                field,
                reason: format!("{file}: {reason}"),
            },
            MotionError::Unsupported { file, reason } => ApiError::Invalid {
                field: "motion".into(),
                reason: format!("{file}: {reason}"),
            },
            e @ MotionError::Io { .. } => ApiError::Internal(e.to_string()),
        }
    }
}

impl From<QueryError> for ApiError {
    fn from(e: QueryError) -> Self {
        match e {
            QueryError::Motion(m) => m.into(),
            other => ApiError::Internal(other.to_string()),
        }
    }
}

/// Where a request's motion comes from.
pub enum MotionInput {
    Inline(Motion),
    File { name: String, bytes: Vec<u8> },
}

/// A motion from flat arrays (`rotations`: frames × joints × 3,
/// `translation`: frames × 3) on a named SMPL skeleton.
pub fn motion_from_parts(
    field: &str,
    name: &str,
    fps: f64,
    skeleton: &str,
    rotations: Vec<[f64; 3]>,
    translation: Vec<[f64; 3]>,
    labels: Labels,
) -> Result<Motion, ApiError> {
    let sk = match skeleton {
        "smpl24" | "" => Skeleton::smpl24(),
        "smpl13" => Skeleton::smpl13(),
        other => {
            return Err(ApiError::invalid(
                format!("{field}.skeleton"),
                format!("'{other}' is not smpl24 or smpl13 (upload other skeletons as a file)"),
            ))
        }
    };
    let frames = translation.len();
    if frames == 0 {
        return Err(ApiError::invalid(
            format!("{field}.translation"),
            "no frames",
        ));
    }
    if rotations.len() != frames * sk.len() {
        return Err(ApiError::invalid(
            format!("{field}.rotations"),
            format!(
                "{} rotations for {frames} frames × {} joints",
                rotations.len(),
                sk.len()
            ),
        ));
    }
    let name = if name.is_empty() { "request" } else { name };
    Motion::new(name, fps, sk, translation, rotations, labels).map_err(|e| prefix(field, e.into()))
}

fn prefix(field: &str, e: ApiError) -> ApiError {
    match e {
        ApiError::Invalid { field: f, reason } => ApiError::Invalid {
            field: format!("{field}.{f}"),
            reason,
        },
        other => other,
    }
}

/// The motion of an input, checked against the duration limit.
pub fn resolve(field: &str, input: MotionInput) -> Result<Motion, ApiError> {
    let m = match input {
        MotionInput::Inline(m) => m,
        MotionInput::File { name, bytes } => {
            let name = if name.is_empty() {
                "upload".to_string()
            } else {
                name
            };
            read_bytes(&name, &bytes, &ReadOptions::default())
                .map_err(|e| prefix(field, e.into()))?
                .motion
        }
    };
    if m.duration_s() > MAX_SECONDS {
        return Err(ApiError::invalid(
            format!("{field}.frames"),
            format!("{:.1} s is over the {MAX_SECONDS} s limit", m.duration_s()),
        ));
    }
    Ok(m)
}

/// Shared server state.
pub struct AppState {
    pub store: Store,
    pub searcher: Searcher,
    /// Permits for CPU-heavy requests (interpolate, lowpass, keyframes,
    /// generate, classify; a stream holds one for its whole life).
    pub workers: Arc<Semaphore>,
    /// The motion language model, when one is installed.
    pub model: Option<Arc<crate::lm::LmSession>>,
    /// Request counts and latencies for `/metrics`.
    pub metrics: Arc<metrics::Metrics>,
}

impl AppState {
    /// Run CPU work on the blocking pool under a worker permit; no permit
    /// free → [`ApiError::Busy`] at once.
    pub async fn heavy<T: Send + 'static>(
        &self,
        what: &str,
        f: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        let permit = self
            .workers
            .clone()
            .try_acquire_owned()
            .map_err(|_| ApiError::Busy(format!("every worker is busy; retry {what} later")))?;
        tokio::task::spawn_blocking(move || {
            let _p = permit;
            f()
        })
        .await
        .map_err(|e| ApiError::Internal(format!("{what} worker failed: {e}")))?
    }
}

/// A query request as both transports give it.
pub struct QueryParams {
    pub motion: MotionInput,
    pub start_s: f64,
    pub frames: usize,
    pub k: usize,
    pub embedding: String,
    pub metric: String,
    pub filters: Vec<(String, String)>,
    pub exact: bool,
}

pub async fn query(state: &AppState, p: QueryParams) -> Result<Vec<QueryHit>, ApiError> {
    let motion = resolve("motion", p.motion)?;
    let embedding = match p.embedding.as_str() {
        "" => Embedding::Stft,
        e => Embedding::parse(e).ok_or_else(|| {
            ApiError::invalid("embedding", format!("'{e}' is not stft, dct or pca"))
        })?,
    };
    let metric = match p.metric.as_str() {
        "" => Metric::Cosine,
        m => Metric::parse(m).ok_or_else(|| {
            ApiError::invalid("metric", format!("'{m}' is not cosine or euclidean"))
        })?,
    };
    if p.k > 1000 {
        return Err(ApiError::invalid("k", format!("{}; at most 1000", p.k)));
    }
    let req = QueryRequest {
        motion,
        start_s: p.start_s,
        frames: if p.frames == 0 { 128 } else { p.frames },
        k: if p.k == 0 { 10 } else { p.k },
        embedding,
        metric,
        filters: p.filters,
        exact: p.exact,
    };
    Ok(state.searcher.query(&req).await?)
}

pub struct InterpolateParams {
    pub input: MotionInput,
    pub target: MotionInput,
    pub band: (usize, usize),
    pub objective: String,
    pub steps: usize,
    pub learning_rate: f64,
    pub despike: bool,
}

pub async fn interpolate(
    state: &AppState,
    p: InterpolateParams,
) -> Result<(Motion, InterpolateReport), ApiError> {
    let a = resolve("input", p.input)?;
    let b = resolve("target", p.target)?;
    let objective = match p.objective.as_str() {
        "" => Embedding::Dct,
        o => Embedding::parse(o).ok_or_else(|| {
            ApiError::invalid("objective", format!("'{o}' is not dct, stft or pca"))
        })?,
    };
    let defaults = InterpolateOptions::default();
    let opts = InterpolateOptions {
        objective,
        band: if p.band == (0, 0) {
            defaults.band
        } else {
            p.band
        },
        steps: if p.steps == 0 {
            defaults.steps
        } else {
            p.steps
        },
        learning_rate: if p.learning_rate == 0.0 {
            defaults.learning_rate
        } else {
            p.learning_rate
        },
    };
    if opts.steps > 5000 {
        return Err(ApiError::invalid(
            "steps",
            format!("{}; at most 5000 per request", opts.steps),
        ));
    }
    let despike = p.despike;
    state
        .heavy("interpolate", move || {
            Ok(interpolate_motions(&a, &b, &opts, despike)?)
        })
        .await
}

pub async fn lowpass(
    state: &AppState,
    motion: MotionInput,
    cutoff: usize,
) -> Result<Motion, ApiError> {
    let m = resolve("motion", motion)?;
    state
        .heavy("lowpass", move || {
            let m = smpl24_at_60(&m)?;
            let out = lowpass_channels(&to_f64(&rows72(&m)), cutoff)
                .map_err(|e| prefix("cutoff", e.into()))?;
            Ok(with_channels(&m, &out))
        })
        .await
}

pub struct KeyframesParams {
    pub motion: MotionInput,
    pub count: usize,
    pub select: String,
    pub inbetween: String,
    pub bpm: f64,
    pub music: Option<(String, Vec<u8>)>,
}

pub async fn keyframes(
    state: &AppState,
    p: KeyframesParams,
) -> Result<(Motion, KeyframeReport), ApiError> {
    let m = resolve("motion", p.motion)?;
    let select = match p.select.as_str() {
        "" => Select::Dp,
        s => Select::parse(s).ok_or_else(|| {
            ApiError::invalid(
                "select",
                format!("'{s}' is not even, onset, percussive, nmfd or dp"),
            )
        })?,
    };
    let inbetween = match p.inbetween.as_str() {
        "" | "slerp" => Inbetween::Slerp,
        "bezier" => Inbetween::Bezier,
        o => {
            return Err(ApiError::invalid(
                "inbetween",
                format!("'{o}' is not slerp or bezier"),
            ))
        }
    };
    let (count, bpm, music) = (p.count, p.bpm, p.music);
    state
        .heavy("keyframes", move || {
            let music = match (music, bpm) {
                (Some((name, bytes)), _) => {
                    let ext = std::path::Path::new(&name)
                        .extension()
                        .and_then(|e| e.to_str())
                        .map(|e| e.to_ascii_lowercase());
                    let a = crate::audio::decode(bytes, &name, ext.as_deref())
                        .map_err(|e| prefix("music", e.into()))?;
                    let (_, f) =
                        crate::audio::analyse(&a, &name).map_err(|e| prefix("music", e.into()))?;
                    Music::Audio(Box::new(f))
                }
                (None, b) if b != 0.0 => Music::Bpm(b),
                _ => Music::None,
            };
            let req = KeyframeRequest {
                select,
                inbetween,
                count,
                music,
            };
            Ok(reconstruct(&m, &req)?)
        })
        .await
}

pub async fn list_motions(state: &AppState) -> Result<Vec<MotionRow>, ApiError> {
    state
        .store
        .motions()
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))
}
