//! The service's transport-neutral layer: requests and responses as domain
//! types, the operations both transports call, and the one error
//! vocabulary with its two translations (HTTP status, gRPC code).
//!
//! [`http`] (axum) and [`grpc`] (tonic) only convert wire types to the
//! requests here and back (ARCHITECTURE rule 1).

pub mod archive;
pub mod auth;
mod error;
pub mod grpc;
pub mod http;
pub mod lm;
pub mod metrics;
pub mod studio;
pub mod ws;

use crate::features::interpolate::{lowpass as lowpass_channels, to_f64, InterpolateOptions};
use crate::features::{rows72, smpl24_at_60, Embedding};
use crate::index::Metric;
use crate::motion::io::json::{MotionJson, MotionParts};
use crate::motion::io::{read_bytes, ReadOptions};
use crate::motion::Motion;
use crate::search::ingest::load_motion;
pub use crate::search::ingest::Stored;
use crate::search::{QueryHit, QueryRequest, QuerySource, Searcher};
use crate::service::interpolate::{interpolate_motions, with_channels, InterpolateReport};
use crate::service::keyframes::{
    reconstruct, Inbetween, KeyframeReport, KeyframeRequest, LearnedModel, Music, Select,
};
use crate::store::Store;
pub use archive::*;
pub use error::ApiError;
use std::sync::Arc;
use tokio::sync::Semaphore;

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

/// An inline JSON motion; errors name `field.<part>`.
pub fn motion_from_json(field: &str, mut m: MotionJson) -> Result<Motion, ApiError> {
    if m.name.is_empty() {
        m.name = "request".into();
    }
    let name = m.name.clone();
    m.into_motion(&name).map_err(|e| prefix(field, e.into()))
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

fn prefix(field: &str, e: ApiError) -> ApiError {
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

/// Shared server state.
pub struct AppState {
    pub store: Store,
    /// The live searcher: writes go through it and reach its indexes at
    /// once; its maintenance runs in the background.
    pub searcher: Arc<Searcher>,
    /// Tokens, scopes, open reads and per-client limits.
    pub auth: Arc<auth::Auth>,
    /// Permits for CPU-heavy requests (interpolate, lowpass, keyframes,
    /// generate, classify; a stream holds one for its whole life).
    pub workers: Arc<Semaphore>,
    /// Permits for queries (the light pool: one per core). Queries wait for
    /// one rather than fail, and never take a heavy permit, so they keep
    /// flowing while generation holds every worker.
    pub light: Arc<Semaphore>,
    /// The motion language model, when one is installed.
    pub model: Option<crate::lm::model::MotionModel>,
    /// The learned in-betweener, when one is installed.
    pub inbetweener: Option<Arc<crate::lm::inbetween::Inbetweener>>,
    /// Request counts and latencies for `/metrics`.
    pub metrics: Arc<metrics::Metrics>,
}

impl AppState {
    pub fn new(
        store: Store,
        searcher: Searcher,
        workers: usize,
        model: Option<crate::lm::model::MotionModel>,
        inbetweener: Option<Arc<crate::lm::inbetween::Inbetweener>>,
        auth: Arc<auth::Auth>,
    ) -> AppState {
        AppState {
            store,
            searcher: Arc::new(searcher),
            auth,
            workers: Arc::new(Semaphore::new(workers.max(1))),
            light: Arc::new(Semaphore::new(
                std::thread::available_parallelism().map_or(2, |n| n.get()),
            )),
            model,
            inbetweener,
            metrics: Default::default(),
        }
    }

    /// The live searcher.
    pub fn searcher(&self) -> Arc<Searcher> {
        self.searcher.clone()
    }

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
                read_bytes(&name, &bytes, &read)
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

    /// May the caller go ahead with a request that needs `need`? `header`
    /// is the `Authorization` header (or gRPC metadata) as sent, `addr` the
    /// peer (the anonymous caller's rate-limit key). Takes one request from
    /// the caller's bucket. Returns who the caller is.
    pub fn authorize(
        &self,
        header: Option<&str>,
        need: auth::Scope,
        addr: Option<std::net::IpAddr>,
    ) -> Result<auth::Principal, ApiError> {
        // The scheme is case-insensitive (RFC 9110 §11.1).
        let token = match header {
            None => None,
            Some(h) => Some(
                h.split_once(' ')
                    .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
                    .map(|(_, t)| t.trim())
                    .ok_or_else(|| {
                        ApiError::Unauthenticated(
                            "the Authorization header must be `Bearer <token>`".into(),
                        )
                    })?,
            ),
        };
        let who = self.auth.authorize(token, need)?;
        self.auth.admit(&who, addr)?;
        Ok(who)
    }

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

pub async fn query(
    state: &AppState,
    p: QueryParams,
    who: &auth::Principal,
) -> Result<Vec<QueryHit>, ApiError> {
    // Motion from video (keypoints, SMPL from an estimator) is searched by
    // the pose embedding unless the request names another. A stored id is
    // looked up once: it must be the caller's to see.
    let (footage, source) = match p.motion {
        MotionInput::File { read, name, bytes } => {
            let footage = read.keypoints.is_some() || read.fps.is_some();
            let m = state
                .resolve("motion", MotionInput::File { read, name, bytes }, who)
                .await?;
            (footage, QuerySource::Motion(m))
        }
        MotionInput::Stored(id) => {
            let row = visible(state, id, who).await.map_err(|e| match e {
                ApiError::NotFound(_) => ApiError::Missing {
                    field: "motion.id".into(),
                    reason: format!("no stored motion {id}"),
                },
                other => other,
            })?;
            (
                row.format == "keypoints" || row.format == "smpl",
                QuerySource::Stored(id),
            )
        }
        inline => (
            false,
            QuerySource::Motion(state.resolve("motion", inline, who).await?),
        ),
    };
    let embedding = match p.embedding.as_str() {
        "" if footage => Embedding::Pose,
        "" => Embedding::Stft,
        e => Embedding::parse(e).ok_or_else(|| {
            ApiError::invalid(
                "embedding",
                format!("'{e}' is not stft, dct, pca, pose or lm"),
            )
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
        source,
        start_s: p.start_s,
        frames: if p.frames == 0 { 128 } else { p.frames },
        k: if p.k == 0 { 10 } else { p.k },
        embedding,
        metric,
        filters: p.filters,
        exact: p.exact,
        collections: who.collections.clone(),
    };
    let _permit = state
        .light
        .clone()
        .acquire_owned()
        .await
        .map_err(|_| ApiError::Busy("the query pool is closed".into()))?;
    let mut hits = state.searcher.query(req).await?;
    for h in &mut hits {
        h.source_path = public_source(&h.source_path);
    }
    Ok(hits)
}

/// A motion's source as API clients see it: its file name, never the
/// server's path to it (`../shared/data/aistpp/motions/x.pkl` → `x.pkl`).
/// The command line, run where the files are, keeps the whole path.
pub fn public_source(path: &str) -> String {
    std::path::Path::new(path)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.to_string())
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
    who: &auth::Principal,
) -> Result<(Motion, InterpolateReport), ApiError> {
    let a = state.resolve("input", p.input, who).await?;
    let b = state.resolve("target", p.target, who).await?;
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
    who: &auth::Principal,
) -> Result<(Motion, KeyframeReport), ApiError> {
    let m = state.resolve("motion", p.motion, who).await?;
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
        "learned" => Inbetween::Learned(LearnedModel(state.inbetweener.clone().ok_or_else(
            || {
                ApiError::Unavailable(
                    "no learned in-betweener is installed (set --inbetweener)".into(),
                )
            },
        )?)),
        o => {
            return Err(ApiError::invalid(
                "inbetween",
                format!("'{o}' is not slerp, bezier or learned"),
            ))
        }
    };
    if p.music.is_some() && p.bpm != 0.0 {
        return Err(ApiError::invalid(
            "bpm",
            "give music or bpm, not both (the music's own beats set the grid)",
        ));
    }
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

pub(crate) fn internal(e: impl std::fmt::Display) -> ApiError {
    ApiError::Internal(e.to_string())
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
