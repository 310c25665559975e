//! REST over axum: JSON in ([`bodies`]), JSON out ([`responses`]); every
//! handler converts and calls one use case of [`crate::service`].

use crate::service::auth::Principal;
use crate::service::interpolate::InterpolateParams;
use crate::service::keyframes::KeyframesParams;
use crate::service::query::QueryParams;
use crate::service::{self, ApiError, Choreo};
use axum::extract::rejection::{JsonRejection, PathRejection};
use axum::extract::{DefaultBodyLimit, Path, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Extension, Json, Router};
use base64::Engine;
use std::sync::Arc;

mod bodies;
mod middleware;
pub mod motion;
pub use motion::MotionJson;
pub mod responses;

pub use bodies::*;
use middleware::*;
use responses::*;

/// The REST API's OpenAPI 3.1 description (checked in; a test holds it to
/// the router).
pub const OPENAPI: &str = include_str!("../../openapi.json");

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

async fn query(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<QueryBody>, JsonRejection>,
) -> Result<Json<QueryResponse>, ApiError> {
    let b = body(b)?;
    let hits = service::query::query(
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
    Ok(Json(QueryResponse { hits }))
}

async fn interpolate(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<InterpolateBody>, JsonRejection>,
) -> Result<Json<WithOutput<crate::service::interpolate::InterpolateReport>>, ApiError> {
    let b = body(b)?;
    let (m, r) = service::interpolate::interpolate(
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
    Ok(Json(WithOutput::new(&m, r)))
}

async fn lowpass(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<LowpassBody>, JsonRejection>,
) -> Result<Json<LowpassResponse>, ApiError> {
    let b = body(b)?;
    let m = service::lowpass::lowpass(&s, source("motion", b.motion)?, b.cutoff, &who).await?;
    Ok(Json(LowpassResponse {
        output: MotionJson::from_motion(&m),
    }))
}

async fn keyframes(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<KeyframesBody>, JsonRejection>,
) -> Result<Json<WithOutput<crate::service::keyframes::KeyframeReport>>, ApiError> {
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
    let (m, r) = service::keyframes::keyframes(
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
    Ok(Json(WithOutput::new(&m, r)))
}

async fn list_motions(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
) -> Result<Json<MotionList>, ApiError> {
    let rows = service::motions::list_motions(&s, &who).await?;
    Ok(Json(MotionList {
        motions: rows.iter().map(MotionSummary::from).collect(),
    }))
}

/// The writer of a request (its principal, set by [`require_scope`]) and
/// its id.
fn actor(who: &Principal, headers: &HeaderMap) -> service::motions::Actor {
    service::motions::Actor {
        name: who.name.clone(),
        request_id: headers
            .get(crate::service::metrics::REQUEST_ID)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string(),
    }
}

async fn ingest(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    headers: HeaderMap,
    b: Result<Json<IngestBody>, JsonRejection>,
) -> Result<(StatusCode, Json<IngestResponse>), ApiError> {
    let b = body(b)?;
    if b.video.is_none() && b.video_offset_s.is_some() {
        return Err(ApiError::invalid("video_offset_s", "given without video"));
    }
    let video = b.video.map(|video| crate::store::VideoLink {
        video,
        video_offset_s: b.video_offset_s.unwrap_or(0.0),
    });
    let stored = service::motions::ingest(
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
        service::motions::Stored::New { .. } => StatusCode::CREATED,
        service::motions::Stored::Existing { .. } => StatusCode::OK,
    };
    Ok((status, Json(stored)))
}

fn motion_id(p: Result<Path<i64>, PathRejection>) -> Result<i64, ApiError> {
    p.map(|Path(id)| id)
        .map_err(|e| ApiError::invalid("id", e.body_text()))
}

async fn model_info(State(s): State<Arc<Choreo>>) -> Result<Json<serde_json::Value>, ApiError> {
    Ok(Json(service::generate::model_info(&s)?))
}

async fn get_motion(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Json<MotionResponse>, ApiError> {
    let (row, m) = service::motions::get_motion(&s, motion_id(id)?, &who).await?;
    // The same names as gRPC's GetMotionResponse: `summary` and `motion`.
    Ok(Json(MotionResponse {
        summary: MotionSummary::from(&row),
        motion: MotionJson::from_motion(&m),
        skeleton: service::generate::skeleton_json(&m.skeleton),
    }))
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
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Response, ApiError> {
    let id = motion_id(id)?;
    let bytes = service::motions::export_glb(&s, id, &who).await?;
    Ok(attachment(
        "model/gltf-binary",
        format!("motion-{id}.glb"),
        bytes,
    ))
}

async fn export_motion(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    id: Result<Path<i64>, PathRejection>,
) -> Result<Response, ApiError> {
    let id = motion_id(id)?;
    let text = service::motions::export_bvh(&s, id, &who).await?;
    Ok(attachment(
        "text/plain; charset=utf-8",
        format!("motion-{id}.bvh"),
        text,
    ))
}

async fn delete_motion(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    headers: HeaderMap,
    id: Result<Path<i64>, PathRejection>,
) -> Result<StatusCode, ApiError> {
    service::motions::delete_motion(&s, motion_id(id)?, &who, &actor(&who, &headers)).await?;
    Ok(StatusCode::NO_CONTENT)
}

async fn list_collections(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
) -> Result<Json<CollectionList>, ApiError> {
    let names = service::motions::list_collections(&s, &who).await?;
    Ok(Json(CollectionList { collections: names }))
}

/// Create a collection (`admin` scope): 201 when new, 200 when it exists.
async fn create_collection(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    headers: HeaderMap,
    b: Result<Json<CollectionBody>, JsonRejection>,
) -> Result<(StatusCode, Json<CollectionCreated>), ApiError> {
    let b = body(b)?;
    let created = service::motions::create_collection(&s, &b.name, &actor(&who, &headers)).await?;
    Ok((
        if created {
            StatusCode::CREATED
        } else {
            StatusCode::OK
        },
        Json(CollectionCreated {
            name: b.name,
            created,
        }),
    ))
}

/// The newest audit entries (`admin` scope).
async fn audit(
    State(s): State<Arc<Choreo>>,
    q: Result<axum::extract::Query<AuditQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<AuditList>, ApiError> {
    let q = q.map_err(|e| ApiError::invalid("limit", e.body_text()))?;
    let entries = service::motions::audit(&s, q.limit).await?;
    Ok(Json(AuditList { entries }))
}

async fn generate(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<GenerateBody>, JsonRejection>,
) -> Result<Json<GenerateResponse>, ApiError> {
    let p = body(b)?.params()?;
    let (m, r) = service::generate::generate(&s, p, &who).await?;
    Ok(Json(GenerateResponse {
        output: MotionJson::from_motion(&m),
        frames: r.frames,
        seconds: r.seconds,
        real_time_factor: r.real_time_factor,
        exemplar: r.exemplar,
        chosen: r.chosen,
        sampling: r.sampling,
    }))
}

async fn classify(
    State(s): State<Arc<Choreo>>,
    Extension(who): Extension<Principal>,
    b: Result<Json<ClassifyBody>, JsonRejection>,
) -> Result<Json<ClassifyResponse>, ApiError> {
    let b = body(b)?;
    let c = service::classify::classify(&s, source("motion", b.motion)?, &who).await?;
    Ok(Json(ClassifyResponse::from(c)))
}

pub fn router(state: Arc<Choreo>, max_body: usize) -> Router {
    Router::new()
        .route(
            "/metrics",
            get(|State(s): State<Arc<Choreo>>| async move {
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
