//! REST over axum: JSON in, JSON out; every handler converts and calls the
//! operation of [`super`].

use super::auth::Principal;
use super::{ApiError, AppState, InterpolateParams, KeyframesParams, MotionInput, QueryParams};
use crate::motion::Labels;
use axum::extract::rejection::{JsonRejection, PathRejection};
use axum::extract::{DefaultBodyLimit, Path, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Extension, Json, Router};
use base64::Engine;
use serde::Deserialize;
use serde_json::json;
use std::sync::Arc;

pub use crate::motion::io::json::MotionJson;

/// The REST API's OpenAPI 3.1 description (checked in; a test holds it to
/// the router).
pub const OPENAPI: &str = include_str!("../../openapi.json");

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileJson {
    #[serde(default)]
    pub name: String,
    pub content_base64: String,
    /// Keypoint layout of a `.npy` / keypoint `.json`: `h36m17` or `mediapipe33`.
    #[serde(default)]
    pub keypoints: Option<String>,
    /// Frame rate of a file that carries none.
    #[serde(default)]
    pub fps: Option<f64>,
    /// The file's up axis (`y`, `-y`, `z`, `-z`, `x`, `-x`).
    #[serde(default)]
    pub up: Option<String>,
    #[serde(default)]
    pub min_confidence: Option<f64>,
    /// Keypoint smoothing before the solve (Gaussian σ, seconds; 0 = off).
    #[serde(default)]
    pub smooth_s: Option<f64>,
}

/// Exactly one of `motion` (inline), `file` (an upload, base64) or `id` (a
/// stored motion).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceJson {
    pub motion: Option<MotionJson>,
    pub file: Option<FileJson>,
    pub id: Option<i64>,
}

fn source(field: &str, s: Option<SourceJson>) -> Result<MotionInput, ApiError> {
    let s = s.ok_or_else(|| ApiError::invalid(field, "missing"))?;
    match (s.motion, s.file, s.id) {
        (None, None, Some(id)) => Ok(MotionInput::Stored(id)),
        (Some(m), None, None) => Ok(MotionInput::Inline(super::motion_from_json(
            &format!("{field}.motion"),
            m,
        )?)),
        (None, Some(f), None) => {
            let bytes = base64::engine::general_purpose::STANDARD
                .decode(f.content_base64.as_bytes())
                .map_err(|e| {
                    ApiError::invalid(format!("{field}.file.content_base64"), e.to_string())
                })?;
            Ok(MotionInput::File {
                read: super::read_options(
                    &format!("{field}.file"),
                    f.keypoints.as_deref(),
                    f.fps,
                    f.up.as_deref(),
                    f.min_confidence,
                    f.smooth_s,
                )?,
                name: f.name,
                bytes,
            })
        }
        _ => Err(ApiError::invalid(
            field,
            "give exactly one of motion, file or id",
        )),
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status =
            StatusCode::from_u16(self.http_status()).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
        let mut resp = (status, Json(self.body())).into_response();
        if status == StatusCode::TOO_MANY_REQUESTS {
            // Worker permits free within a request's time: one second is a
            // fair first back-off. A rate limit says when its bucket refills.
            let secs = match &self {
                ApiError::RateLimited { retry_after_s, .. } => *retry_after_s,
                _ => 1,
            };
            resp.headers_mut().insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from(secs),
            );
        }
        resp
    }
}

/// Unknown paths: the error table's JSON body, not an empty 404.
async fn not_found(uri: axum::http::Uri) -> Response {
    (
        StatusCode::NOT_FOUND,
        Json(json!({"error": {"code": "not_found", "reason": format!("no route {}", uri.path())}})),
    )
        .into_response()
}

/// A known path with the wrong method: 405 with a JSON body (axum's
/// `Allow` header is kept).
async fn method_json(req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    let method = req.method().clone();
    let path = req.uri().path().to_string();
    let resp = next.run(req).await;
    if resp.status() != StatusCode::METHOD_NOT_ALLOWED {
        return resp;
    }
    let allow = resp.headers().get(axum::http::header::ALLOW).cloned();
    let mut out = (
        StatusCode::METHOD_NOT_ALLOWED,
        Json(json!({"error": {"code": "method_not_allowed", "reason": format!("{method} is not allowed on {path}")}})),
    )
        .into_response();
    if let Some(a) = allow {
        out.headers_mut().insert(axum::http::header::ALLOW, a);
    }
    out
}

fn body<T>(b: Result<Json<T>, JsonRejection>) -> Result<T, ApiError> {
    b.map(|Json(x)| x).map_err(|r| {
        if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::TooLarge("the request body is over the server's limit (--max-body-mb)".into())
        } else {
            decode_error(&r.body_text())
        }
    })
}

/// A JSON body serde could not read, as an error naming the field: a
/// misspelt field is named as the request spelt it ("start" for
/// "start_s"), not passed over.
pub(crate) fn decode_error(text: &str) -> ApiError {
    match text
        .split_once("unknown field `")
        .and_then(|(_, rest)| rest.split_once('`'))
    {
        Some((field, rest)) => ApiError::invalid(
            field,
            format!(
                "unknown field{}",
                rest.split(" at line").next().unwrap_or("")
            ),
        ),
        None => ApiError::invalid("body", text),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueryBody {
    pub motion: Option<SourceJson>,
    #[serde(default)]
    pub start_s: f64,
    #[serde(default)]
    pub frames: usize,
    #[serde(default)]
    pub k: usize,
    #[serde(default)]
    pub embedding: String,
    #[serde(default)]
    pub metric: String,
    #[serde(default)]
    pub filters: Labels,
    #[serde(default)]
    pub exact: bool,
}

async fn query(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<QueryBody>, JsonRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let b = body(b)?;
    let hits = super::query(
        &s,
        QueryParams {
            motion: source("motion", b.motion)?,
            start_s: b.start_s,
            frames: b.frames,
            k: b.k,
            embedding: b.embedding,
            metric: b.metric,
            filters: b.filters.into_iter().collect(),
            exact: b.exact,
        },
        &who,
    )
    .await?;
    Ok(Json(json!({ "hits": hits })))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InterpolateBody {
    pub input: Option<SourceJson>,
    pub target: Option<SourceJson>,
    #[serde(default)]
    pub band: Option<[usize; 2]>,
    #[serde(default)]
    pub objective: String,
    #[serde(default)]
    pub steps: usize,
    #[serde(default)]
    pub learning_rate: f64,
    #[serde(default)]
    pub despike: bool,
}

async fn interpolate(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<InterpolateBody>, JsonRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let b = body(b)?;
    let (m, r) = super::interpolate(
        &s,
        InterpolateParams {
            input: source("input", b.input)?,
            target: source("target", b.target)?,
            band: b.band.map(|[a, c]| (a, c)).unwrap_or((0, 0)),
            objective: b.objective,
            steps: b.steps,
            learning_rate: b.learning_rate,
            despike: b.despike,
        },
        &who,
    )
    .await?;
    let mut v = serde_json::to_value(&r).map_err(|e| ApiError::Internal(e.to_string()))?;
    v["output"] = serde_json::to_value(MotionJson::from_motion(&m))
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok(Json(v))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LowpassBody {
    pub motion: Option<SourceJson>,
    pub cutoff: usize,
}

async fn lowpass(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<LowpassBody>, JsonRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let b = body(b)?;
    let m = super::lowpass(&s, source("motion", b.motion)?, b.cutoff, &who).await?;
    Ok(Json(json!({ "output": MotionJson::from_motion(&m) })))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyframesBody {
    pub motion: Option<SourceJson>,
    pub count: usize,
    #[serde(default)]
    pub select: String,
    #[serde(default)]
    pub inbetween: String,
    #[serde(default)]
    pub bpm: f64,
    pub music: Option<FileJson>,
}

async fn keyframes(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<KeyframesBody>, JsonRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let b = body(b)?;
    let music = match b.music {
        Some(f) => Some((
            f.name,
            base64::engine::general_purpose::STANDARD
                .decode(f.content_base64.as_bytes())
                .map_err(|e| ApiError::invalid("music.content_base64", e.to_string()))?,
        )),
        None => None,
    };
    let (m, r) = super::keyframes(
        &s,
        KeyframesParams {
            motion: source("motion", b.motion)?,
            count: b.count,
            select: b.select,
            inbetween: b.inbetween,
            bpm: b.bpm,
            music,
        },
        &who,
    )
    .await?;
    let mut v = serde_json::to_value(&r).map_err(|e| ApiError::Internal(e.to_string()))?;
    v["output"] = serde_json::to_value(MotionJson::from_motion(&m))
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok(Json(v))
}

fn summary(r: &crate::store::MotionRow) -> serde_json::Value {
    let mut v = json!({"id": r.id, "source_path": super::public_source(&r.source_path), "format": r.format, "fps": r.fps,
           "frames": r.frames, "joints": r.joints, "skeleton": r.skeleton,
           "duration_s": r.duration_s, "labels": r.labels, "collection": r.collection});
    if let Some(link) = &r.video {
        v["video"] = json!(link.video);
        v["video_offset_s"] = json!(link.video_offset_s);
    }
    v
}

async fn list_motions(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let rows = super::list_motions(&s, &who).await?;
    let motions: Vec<serde_json::Value> = rows.iter().map(summary).collect();
    Ok(Json(json!({ "motions": motions })))
}

fn bearer(h: &HeaderMap) -> Option<&str> {
    h.get(axum::http::header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IngestBody {
    pub motion: Option<SourceJson>,
    #[serde(default)]
    pub labels: Labels,
    /// The footage the motion was estimated from (path or URL).
    #[serde(default)]
    pub video: Option<String>,
    /// Video time of the motion's first frame, seconds (default 0).
    #[serde(default)]
    pub video_offset_s: Option<f64>,
    /// The collection to store it in (default `default`); it must exist
    /// and be the token's.
    #[serde(default)]
    pub collection: Option<String>,
}

/// The writer of a request (its principal, set by [`require_scope`]) and
/// its id.
fn actor(who: &Principal, headers: &HeaderMap) -> super::Actor {
    super::Actor {
        name: who.name.clone(),
        request_id: headers
            .get(super::metrics::REQUEST_ID)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string(),
    }
}

async fn ingest(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    headers: HeaderMap,
    b: Result<Json<IngestBody>, JsonRejection>,
) -> Result<(StatusCode, Json<serde_json::Value>), ApiError> {
    let b = body(b)?;
    if b.video.is_none() && b.video_offset_s.is_some() {
        return Err(ApiError::invalid("video_offset_s", "given without video"));
    }
    let video = b.video.map(|video| crate::store::VideoLink {
        video,
        video_offset_s: b.video_offset_s.unwrap_or(0.0),
    });
    let stored = super::ingest(
        &s,
        source("motion", b.motion)?,
        b.labels,
        video,
        b.collection,
        &who,
        &actor(&who, &headers),
    )
    .await?;
    let status = match stored.stored {
        super::Stored::New { .. } => StatusCode::CREATED,
        super::Stored::Existing { .. } => StatusCode::OK,
    };
    Ok((
        status,
        Json(serde_json::to_value(stored).map_err(super::internal)?),
    ))
}

fn motion_id(p: Result<Path<i64>, PathRejection>) -> Result<i64, ApiError> {
    p.map(|Path(id)| id)
        .map_err(|e| ApiError::invalid("id", e.body_text()))
}

async fn model_info(State(s): State<Arc<AppState>>) -> Result<Json<serde_json::Value>, ApiError> {
    Ok(Json(super::lm::model_info(&s)?))
}

async fn get_motion(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let (row, m) = super::get_motion(&s, motion_id(id)?, &who).await?;
    Ok(Json(json!({
        "motion": summary(&row),
        "data": MotionJson::from_motion(&m),
        "skeleton": super::lm::skeleton_json(&m.skeleton),
    })))
}

/// A download: its content type and file name.
fn attachment(content_type: &str, filename: String, body: impl IntoResponse) -> Response {
    (
        [
            (axum::http::header::CONTENT_TYPE, content_type.to_string()),
            (
                axum::http::header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{filename}\""),
            ),
        ],
        body,
    )
        .into_response()
}

async fn export_glb(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Response, ApiError> {
    let id = motion_id(id)?;
    let bytes = super::export_glb(&s, id, &who).await?;
    Ok(attachment(
        "model/gltf-binary",
        format!("motion-{id}.glb"),
        bytes,
    ))
}

async fn export_motion(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Response, ApiError> {
    let id = motion_id(id)?;
    let text = super::export_bvh(&s, id, &who).await?;
    Ok(attachment(
        "text/plain; charset=utf-8",
        format!("motion-{id}.bvh"),
        text,
    ))
}

async fn delete_motion(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    headers: HeaderMap,
    id: Result<Path<i64>, PathRejection>,
) -> Result<StatusCode, ApiError> {
    super::delete_motion(&s, motion_id(id)?, &who, &actor(&who, &headers)).await?;
    Ok(StatusCode::NO_CONTENT)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AuditQuery {
    #[serde(default = "default_audit_limit")]
    pub limit: i64,
}

fn default_audit_limit() -> i64 {
    100
}

async fn list_collections(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let names = super::list_collections(&s, &who).await?;
    Ok(Json(json!({ "collections": names })))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectionBody {
    pub name: String,
}

/// Create a collection (`admin` scope): 201 when new, 200 when it exists.
async fn create_collection(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    headers: HeaderMap,
    b: Result<Json<CollectionBody>, JsonRejection>,
) -> Result<(StatusCode, Json<serde_json::Value>), ApiError> {
    let b = body(b)?;
    let created = super::create_collection(&s, &b.name, &actor(&who, &headers)).await?;
    Ok((
        if created {
            StatusCode::CREATED
        } else {
            StatusCode::OK
        },
        Json(json!({ "name": b.name, "created": created })),
    ))
}

/// The newest audit entries (`admin` scope).
async fn audit(
    State(s): State<Arc<AppState>>,
    q: Result<axum::extract::Query<AuditQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let q = q.map_err(|e| ApiError::invalid("limit", e.body_text()))?;
    let entries = super::audit(&s, q.limit).await?;
    Ok(Json(json!({ "entries": entries })))
}

/// Every `/v1` route needs its scope ([`super::auth::rest_scope`]): the
/// bearer token (or, where a browser cannot set headers, as on a WebSocket,
/// `?access_token=`), or nothing for reads under `--public-read`. One
/// request is taken from the caller's bucket; the caller's principal goes
/// into the request for the handlers.
async fn require_scope(
    State(s): State<Arc<AppState>>,
    mut req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let Some(need) = super::auth::rest_scope(req.method(), req.uri().path()) else {
        return next.run(req).await;
    };
    let addr = req
        .extensions()
        .get::<axum::extract::ConnectInfo<std::net::SocketAddr>>()
        .map(|c| c.0.ip());
    let header = bearer(req.headers()).map(str::to_string).or_else(|| {
        req.uri().query().and_then(|q| {
            q.split('&')
                .find_map(|kv| kv.strip_prefix("access_token="))
                .map(|t| format!("Bearer {t}"))
        })
    });
    match s.authorize(header.as_deref(), need, addr) {
        Ok(who) => {
            req.extensions_mut().insert(who);
            next.run(req).await
        }
        Err(e) => {
            // Read (and drop) a small body before answering, so that a
            // client still sending it gets the answer rather than a reset
            // connection; a large one is not read for a caller refused.
            let _ = axum::body::to_bytes(req.into_body(), REFUSED_BODY_DRAIN).await;
            e.into_response()
        }
    }
}

/// Bytes of a refused request's body read before the answer.
const REFUSED_BODY_DRAIN: usize = 4 << 20;

/// Sampling settings as JSON, all optional. Without a temperature the
/// request gets the recommended setting (`lm::generate::RECOMMENDED`), with
/// its own `top_k` / `top_p` where given; `"temperature": 0` is greedy.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingJson {
    pub temperature: Option<f64>,
    pub top_k: Option<usize>,
    pub top_p: Option<f64>,
    #[serde(default)]
    pub seed: u64,
    /// Classifier-free guidance toward the labels (1 = plain
    /// conditioning); absent = the recommended value.
    pub guidance: Option<f64>,
}

impl SamplingJson {
    pub fn to_sampling(&self) -> crate::lm::Sampling {
        let r = crate::lm::Sampling::recommended(self.seed);
        let guidance = self.guidance.unwrap_or(r.guidance);
        match self.temperature {
            None => crate::lm::Sampling {
                top_k: self.top_k.unwrap_or(r.top_k),
                top_p: self.top_p.unwrap_or(r.top_p),
                guidance,
                ..r
            },
            Some(t) => crate::lm::Sampling {
                temperature: t,
                top_k: self.top_k.unwrap_or(0),
                top_p: self.top_p.unwrap_or(1.0),
                seed: self.seed,
                guidance,
            },
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GenerateBody {
    #[serde(default)]
    pub labels: Labels,
    #[serde(default)]
    pub frames: usize,
    pub prompt: Option<SourceJson>,
    #[serde(default)]
    pub prompt_joints: Vec<String>,
    pub seed_motion: Option<SourceJson>,
    #[serde(default)]
    pub sampling: SamplingJson,
}

impl GenerateBody {
    /// The request both REST and the WebSocket stream take.
    pub(crate) fn params(self) -> Result<super::lm::GenerateParams, ApiError> {
        Ok(super::lm::GenerateParams {
            labels: self.labels,
            frames: self.frames,
            prompt: self.prompt.map(|x| source("prompt", Some(x))).transpose()?,
            prompt_joints: self.prompt_joints,
            seed_motion: self
                .seed_motion
                .map(|x| source("seed_motion", Some(x)))
                .transpose()?,
            sampling: self.sampling.to_sampling(),
        })
    }
}

async fn generate(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<GenerateBody>, JsonRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let p = body(b)?.params()?;
    let (m, r) = super::lm::generate(&s, p, &who).await?;
    Ok(Json(json!({
        "output": MotionJson::from_motion(&m),
        "frames": r.frames,
        "seconds": r.seconds,
        "real_time_factor": r.real_time_factor,
    })))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassifyBody {
    pub motion: Option<SourceJson>,
}

async fn classify(
    State(s): State<Arc<AppState>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<ClassifyBody>, JsonRejection>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let b = body(b)?;
    let c = super::lm::classify(&s, source("motion", b.motion)?, &who).await?;
    let kinds: Vec<serde_json::Value> = c
        .iter()
        .map(|(k, v)| {
            json!({
                "kind": k,
                "label": v.first().map(|x| x.0.clone()),
                "scores": v.iter().map(|(l, p)| json!({"label": l, "probability": p})).collect::<Vec<_>>(),
            })
        })
        .collect();
    Ok(Json(json!({ "classes": kinds })))
}

/// The REST routes; `max_body` bytes per request.
/// Records every REST request (route template, status, latency).
async fn track(
    State(s): State<Arc<AppState>>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let route = req
        .extensions()
        .get::<axum::extract::MatchedPath>()
        .map(|p| p.as_str().to_string())
        .unwrap_or_else(|| "unmatched".into());
    tracing::Span::current().record("route", route.as_str());
    let t0 = std::time::Instant::now();
    let resp = next.run(req).await;
    s.metrics.observe(
        "http",
        &route,
        resp.status().as_str(),
        t0.elapsed().as_secs_f64(),
    );
    resp
}

/// One span per request: its id (the caller's `x-request-id`, or a new
/// one), method and route; one log line when it is answered, with the
/// status and duration; the id echoed in the answer's `x-request-id`.
async fn request_span(mut req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    use super::metrics::{request_id, REQUEST_ID};
    let id = request_id(req.headers());
    let span = tracing::info_span!(
        "request",
        id = %id,
        transport = "http",
        method = %req.method(),
        route = tracing::field::Empty,
    );
    if let Ok(v) = axum::http::HeaderValue::from_str(&id) {
        req.headers_mut().insert(REQUEST_ID, v);
    }
    let t0 = std::time::Instant::now();
    let mut resp = tracing::Instrument::instrument(
        async move {
            let resp = next.run(req).await;
            tracing::info!(
                status = resp.status().as_u16(),
                duration_ms = t0.elapsed().as_secs_f64() * 1e3,
                "answered"
            );
            resp
        },
        span,
    )
    .await;
    if let Ok(v) = axum::http::HeaderValue::from_str(&id) {
        resp.headers_mut().insert(REQUEST_ID, v);
    }
    resp
}

pub fn router(state: Arc<AppState>, max_body: usize) -> Router {
    Router::new()
        .route(
            "/metrics",
            get(|State(s): State<Arc<AppState>>| async move {
                (
                    [(
                        axum::http::header::CONTENT_TYPE,
                        "text/plain; version=0.0.4",
                    )],
                    s.metrics.render(),
                )
            }),
        )
        .route("/healthz", get(|| async { "ok" }))
        .route("/readyz", get(|| async { "ready" }))
        .route("/v1/query", post(query))
        .route("/v1/interpolate", post(interpolate))
        .route("/v1/lowpass", post(lowpass))
        .route("/v1/keyframes", post(keyframes))
        .route("/v1/generate", post(generate))
        .route("/v1/generate/ws", get(super::ws::generate))
        .route("/v1/duet/ws", get(super::ws::duet))
        .route("/v1/classify", post(classify))
        .route("/v1/model", get(model_info))
        .route("/v1/motions", get(list_motions).post(ingest))
        .route("/v1/motions/{id}", get(get_motion).delete(delete_motion))
        .route("/v1/motions/{id}/bvh", get(export_motion))
        .route("/v1/motions/{id}/glb", get(export_glb))
        .route("/v1/audit", get(audit))
        .route(
            "/v1/collections",
            get(list_collections).post(create_collection),
        )
        .route(
            "/openapi.json",
            get(|| async {
                (
                    [(axum::http::header::CONTENT_TYPE, "application/json")],
                    OPENAPI,
                )
            }),
        )
        .merge(super::studio::routes())
        .layer(DefaultBodyLimit::max(max_body))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            require_scope,
        ))
        .route_layer(axum::middleware::from_fn_with_state(state.clone(), track))
        .fallback(not_found)
        .layer(axum::middleware::from_fn(method_json))
        .layer(axum::middleware::from_fn(request_span))
        .with_state(state)
}
