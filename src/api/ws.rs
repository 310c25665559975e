//! WebSocket streams for browsers, which cannot speak gRPC: generation as
//! it is decoded (`GET /v1/generate/ws`) and the live duet (`GET
//! /v1/duet/ws`). Messages are JSON text and mirror the gRPC ones, with
//! joint triples nested as in the REST motion JSON:
//!
//! - generate: the client sends one message, the body of `POST
//!   /v1/generate`; the server answers `{"start": {"skeleton", "fps"}}`, one
//!   `{"frame": {"index", "rotations": [[x, y, z] per joint], "translation",
//!   "latency_ms"}}` per frame, then `{"end": {"frames", "seconds"}}` and a
//!   normal close.
//! - duet: the first message is the set-up `{"labels", "prompt_joints",
//!   "sampling", "frame"?}` (gRPC `DuetRequest`); each later one is
//!   `{"frame": MOTION}`, a one-frame motion in the REST motion JSON at the
//!   model's frame rate. Each frame in gets one `{"frame": …}` out.
//!
//! Errors use the REST error body (`{"error": {"code", "field", "reason"}}`)
//! and the same table. After an error the server closes the socket and
//! stops its work; a client that closes mid-stream stops it too (the
//! generation worker sees its channel dropped), so no task outlives the
//! socket.

use super::http::MotionJson;
use super::http::{decode_error, GenerateBody, SamplingJson};
use crate::motion::Labels;
use crate::service::generate::{self as lm, StreamFrame};
use crate::service::{self, ApiError, Choreo};
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::response::Response;
use serde::Deserialize;
use serde_json::{json, Value};
use std::sync::Arc;
use std::time::Instant;

/// Largest message a client may send (one frame, or a generate request
/// with an inline prompt).
pub const MAX_MESSAGE_BYTES: usize = 16 << 20;

pub async fn generate(
    State(s): State<Arc<Choreo>>,
    axum::Extension(who): axum::Extension<service::auth::Principal>,
    ws: WebSocketUpgrade,
) -> Response {
    ws.max_message_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| generate_socket(s, socket, who))
}

pub async fn duet(State(s): State<Arc<Choreo>>, ws: WebSocketUpgrade) -> Response {
    ws.max_message_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| duet_socket(s, socket))
}

fn frame_json(f: &StreamFrame) -> Value {
    json!({"frame": {
        "index": f.index,
        "rotations": f.rotations,
        "translation": f.translation,
        "latency_ms": f.latency_ms,
    }})
}

async fn send(socket: &mut WebSocket, v: &Value) -> bool {
    socket
        .send(Message::Text(v.to_string().into()))
        .await
        .is_ok()
}

/// Say what went wrong, then close (policy violation for bad input,
/// internal error otherwise).
async fn fail(mut socket: WebSocket, e: ApiError) {
    let _ = send(&mut socket, &e.body()).await;
    let code = match e {
        ApiError::Internal(_) => 1011,
        ApiError::Busy(_) | ApiError::Unavailable(_) => 1013,
        _ => 1008,
    };
    let reason: String = e.kind().into();
    let _ = socket
        .send(Message::Close(Some(CloseFrame {
            code,
            reason: reason.into(),
        })))
        .await;
}

/// The next JSON text message, parsed; `Ok(None)` when the client closed.
async fn next_json<T: for<'de> Deserialize<'de>>(
    socket: &mut WebSocket,
) -> Result<Option<T>, ApiError> {
    loop {
        match socket.recv().await {
            None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return Ok(None),
            Some(Ok(Message::Text(t))) => {
                return serde_json::from_str(t.as_str())
                    .map(Some)
                    .map_err(|e| decode_error(&e.to_string()))
            }
            Some(Ok(Message::Binary(_))) => {
                return Err(ApiError::invalid(
                    "message",
                    "binary message; send JSON text",
                ))
            }
            Some(Ok(_)) => continue, // ping / pong
        }
    }
}

async fn generate_socket(state: Arc<Choreo>, mut socket: WebSocket, who: service::auth::Principal) {
    let body: GenerateBody = match next_json(&mut socket).await {
        Ok(Some(b)) => b,
        Ok(None) => return,
        Err(e) => return fail(socket, e).await,
    };
    let started = Instant::now();
    let rx = async {
        let (skeleton, fps) = lm::stream_format(&state)?;
        let s = lm::generate_stream(&state, body.params()?, &who).await?;
        Ok::<_, ApiError>((skeleton, fps, s.exemplar, s.sampling, s.frames))
    }
    .await;
    let (skeleton, fps, exemplar, sampling, mut rx) = match rx {
        Ok(x) => x,
        Err(e) => return fail(socket, e).await,
    };
    if !send(
        &mut socket,
        &json!({"start": {"skeleton": skeleton, "fps": fps, "exemplar": exemplar, "sampling": sampling}}),
    )
    .await
    {
        return;
    }
    let mut frames = 0usize;
    loop {
        tokio::select! {
            f = rx.recv() => match f {
                Some(Ok(f)) => {
                    frames += 1;
                    // A failed send means the client left: dropping `rx`
                    // stops the worker.
                    if !send(&mut socket, &frame_json(&f)).await {
                        return;
                    }
                }
                Some(Err(e)) => return fail(socket, e).await,
                None => break,
            },
            m = socket.recv() => match m {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return,
                Some(Ok(Message::Text(_) | Message::Binary(_))) => {
                    return fail(
                        socket,
                        ApiError::invalid("message", "a generation takes one request message"),
                    )
                    .await
                }
                Some(Ok(_)) => {}
            },
        }
    }
    let end = json!({"end": {"frames": frames, "seconds": started.elapsed().as_secs_f64()}});
    if send(&mut socket, &end).await {
        let _ = socket.send(Message::Close(None)).await;
    }
}

/// The duet's first message (gRPC `DuetRequest`).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DuetSetup {
    #[serde(default)]
    labels: Labels,
    #[serde(default)]
    prompt_joints: Vec<String>,
    #[serde(default)]
    sampling: SamplingJson,
    frame: Option<MotionJson>,
}

/// Every later duet message.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DuetFrame {
    frame: MotionJson,
}

async fn duet_socket(state: Arc<Choreo>, mut socket: WebSocket) {
    let setup: DuetSetup = match next_json(&mut socket).await {
        Ok(Some(s)) => s,
        Ok(None) => return,
        Err(e) => return fail(socket, e).await,
    };
    let session = match crate::service::duet::DuetSession::open(
        &state,
        &setup.labels,
        &setup.prompt_joints,
        (setup.sampling.to_sampling(), setup.sampling.named()),
    ) {
        Ok(s) => s,
        Err(e) => return fail(socket, e).await,
    };
    let (frames_in, mut frames_out) = crate::service::duet::duet(session);
    let mut pending = setup.frame;
    loop {
        let frame = match pending.take() {
            Some(f) => f,
            None => match next_json::<DuetFrame>(&mut socket).await {
                Ok(Some(m)) => m.frame,
                Ok(None) => return,
                Err(e) => return fail(socket, e).await,
            },
        };
        let motion = match frame
            .into_parts("frame")
            .and_then(|p| service::input::motion_from_parts("frame", p))
        {
            Ok(m) => m,
            Err(e) => return fail(socket, e).await,
        };
        if frames_in.send(Ok(motion)).await.is_err() {
            return;
        }
        match frames_out.recv().await {
            Some(Ok(f)) => {
                if !send(&mut socket, &frame_json(&f)).await {
                    return;
                }
            }
            Some(Err(e)) => return fail(socket, e).await,
            None => return,
        }
    }
}
