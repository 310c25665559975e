//! The REST responses, typed: each handler builds one of these from the use
//! case's result, so the JSON a client gets has one definition here (the
//! OpenAPI's schemas name the same fields; `openapi_json_matches_the_router`
//! and the schemathesis run hold the two together).

use super::MotionJson;
use crate::motion::{Labels, Motion};
use crate::search::{IngestOutcome, QueryHit};
use crate::service;
use crate::store::{AuditRow, MotionRow};
use serde::Serialize;

/// `POST /v1/query`.
#[derive(Serialize)]
pub struct QueryResponse {
    pub hits: Vec<QueryHit>,
}

/// A use case's report with the motion it made (`interpolate`,
/// `keyframes`): the report's fields, then `output`.
#[derive(Serialize)]
pub struct WithOutput<R: Serialize> {
    #[serde(flatten)]
    pub report: R,
    pub output: MotionJson,
}

impl<R: Serialize> WithOutput<R> {
    pub fn new(m: &Motion, report: R) -> Self {
        WithOutput {
            report,
            output: MotionJson::from_motion(m),
        }
    }
}

/// `POST /v1/lowpass`.
#[derive(Serialize)]
pub struct LowpassResponse {
    pub output: MotionJson,
}

/// A stored motion's summary (list, get): the same fields as gRPC's
/// `MotionSummary`. `source_path` is the file name only, never the
/// server's path.
#[derive(Serialize)]
pub struct MotionSummary {
    pub id: i64,
    pub source_path: String,
    pub format: String,
    pub fps: f64,
    pub frames: i64,
    pub joints: i64,
    pub skeleton: String,
    pub duration_s: f64,
    pub labels: Labels,
    pub collection: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub video: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub video_offset_s: Option<f64>,
}

impl From<&MotionRow> for MotionSummary {
    fn from(r: &MotionRow) -> Self {
        MotionSummary {
            id: r.id,
            source_path: service::query::public_source(&r.source_path),
            format: r.format.clone(),
            fps: r.fps,
            frames: r.frames,
            joints: r.joints,
            skeleton: r.skeleton.clone(),
            duration_s: r.duration_s,
            labels: r.labels.clone(),
            collection: r.collection.clone(),
            video: r.video.as_ref().map(|v| v.video.clone()),
            video_offset_s: r.video.as_ref().map(|v| v.video_offset_s),
        }
    }
}

/// `GET /v1/motions`.
#[derive(Serialize)]
pub struct MotionList {
    pub motions: Vec<MotionSummary>,
}

/// `GET /v1/motions/{id}`: the same names as gRPC's `GetMotionResponse`,
/// with the skeleton (names, parents, offsets) for forward kinematics.
#[derive(Serialize)]
pub struct MotionResponse {
    pub summary: MotionSummary,
    pub motion: MotionJson,
    pub skeleton: serde_json::Value,
}

/// `POST /v1/motions`: `status` (`new` / `existing`), the id, the windows
/// of a new motion, and the labels as stored now when they were merged.
pub type IngestResponse = IngestOutcome;

/// `GET /v1/collections`.
#[derive(Serialize)]
pub struct CollectionList {
    pub collections: Vec<String>,
}

/// `POST /v1/collections`.
#[derive(Serialize)]
pub struct CollectionCreated {
    pub name: String,
    pub created: bool,
}

/// `GET /v1/audit`.
#[derive(Serialize)]
pub struct AuditList {
    pub entries: Vec<AuditRow>,
}

/// `POST /v1/generate`.
#[derive(Serialize)]
pub struct GenerateResponse {
    pub output: MotionJson,
    pub frames: usize,
    pub seconds: f64,
    pub real_time_factor: f64,
    /// The style exemplar the generation started from, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exemplar: Option<service::generate::ExemplarUsed>,
    /// Best of N: which candidate came back, when more than one was made.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub chosen: Option<service::generate::ChosenCandidate>,
    /// The sampling it ran with, defaults filled in.
    pub sampling: crate::lm::Sampling,
}

/// One label's probability.
#[derive(Serialize)]
pub struct Score {
    pub label: String,
    pub probability: f64,
}

/// One label kind's classification: the best label and every score, best
/// first.
#[derive(Serialize)]
pub struct KindScores {
    pub kind: String,
    pub label: Option<String>,
    pub scores: Vec<Score>,
}

/// `POST /v1/classify`.
#[derive(Serialize)]
pub struct ClassifyResponse {
    pub classes: Vec<KindScores>,
}

impl From<service::classify::Classes> for ClassifyResponse {
    fn from(c: service::classify::Classes) -> Self {
        ClassifyResponse {
            classes: c
                .into_iter()
                .map(|(kind, v)| KindScores {
                    kind,
                    label: v.first().map(|x| x.0.clone()),
                    scores: v
                        .into_iter()
                        .map(|(label, probability)| Score { label, probability })
                        .collect(),
                })
                .collect(),
        }
    }
}
