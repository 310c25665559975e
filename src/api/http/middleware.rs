//! The REST middleware: scopes and tokens (`require_scope`), request spans
//! and ids, metrics, and JSON bodies for unknown paths and wrong methods.

use crate::service::Choreo;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;
use std::sync::Arc;

/// Unknown paths: the error table's JSON body, not an empty 404.
pub(super) async fn not_found(uri: axum::http::Uri) -> Response {
    (
        StatusCode::NOT_FOUND,
        Json(json!({"error": {"code": "not_found", "reason": format!("no route {}", uri.path())}})),
    )
        .into_response()
}

/// A known path with the wrong method: 405 with a JSON body (axum's
/// `Allow` header is kept).
pub(super) async fn method_json(
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
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

pub(super) fn bearer(h: &HeaderMap) -> Option<&str> {
    h.get(axum::http::header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
}

/// Every `/v1` route needs its scope ([`super::auth::rest_scope`]): the
/// bearer token (or, where a browser cannot set headers, as on a WebSocket,
/// `?access_token=`), or nothing for reads under `--public-read`. One
/// request is taken from the caller's bucket; the caller's principal goes
/// into the request for the handlers.
pub(super) async fn require_scope(
    State(s): State<Arc<Choreo>>,
    mut req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let Some(need) = crate::service::auth::rest_scope(req.method(), req.uri().path()) else {
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
pub(super) const REFUSED_BODY_DRAIN: usize = 4 << 20;

/// The REST routes; `max_body` bytes per request.
/// Records every REST request (route template, status, latency).
pub(super) async fn track(
    State(s): State<Arc<Choreo>>,
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
pub(super) async fn request_span(
    mut req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    use crate::service::metrics::{request_id, REQUEST_ID};
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
