//! gRPC over tonic (`proto/choreo/v1/choreo.proto`): every method converts
//! and calls the operation of [`super`].

use super::{ApiError, AppState, InterpolateParams, KeyframesParams, MotionInput, QueryParams};
use crate::motion::Motion;
use std::sync::Arc;
use tonic::{Request, Response, Status};

#[allow(clippy::all, missing_docs)]
pub mod pb {
    tonic::include_proto!("choreo.v1");
}

use pb::choreo_server::{Choreo, ChoreoServer};

impl From<ApiError> for Status {
    fn from(e: ApiError) -> Status {
        Status::new(e.grpc_code(), e.to_string())
    }
}

fn triples(field: &str, v: &[f64]) -> Result<Vec<[f64; 3]>, ApiError> {
    if v.len() % 3 != 0 {
        return Err(ApiError::invalid(
            field,
            format!("{} values is not a multiple of 3", v.len()),
        ));
    }
    Ok(v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect())
}

fn source(field: &str, s: Option<pb::MotionSource>) -> Result<MotionInput, ApiError> {
    match s.and_then(|s| s.source) {
        Some(pb::motion_source::Source::Motion(m)) => {
            Ok(MotionInput::Inline(super::motion_from_parts(
                &format!("{field}.motion"),
                &m.name,
                m.fps,
                &m.skeleton,
                triples(&format!("{field}.motion.rotations"), &m.rotations)?,
                triples(&format!("{field}.motion.translation"), &m.translation)?,
                m.labels.into_iter().collect(),
            )?))
        }
        Some(pb::motion_source::Source::File(f)) => Ok(MotionInput::File {
            name: f.name,
            bytes: f.content,
        }),
        None => Err(ApiError::invalid(field, "missing")),
    }
}

pub fn motion_pb(m: &Motion) -> pb::Motion {
    pb::Motion {
        fps: m.fps,
        skeleton: m.skeleton.kind.clone(),
        rotations: m.rotations.iter().flat_map(|r| r.iter().copied()).collect(),
        translation: m.trans.iter().flat_map(|r| r.iter().copied()).collect(),
        labels: m.labels.clone().into_iter().collect(),
        name: m.name.clone(),
    }
}

pub struct ChoreoGrpc {
    pub state: Arc<AppState>,
}

#[tonic::async_trait]
impl Choreo for ChoreoGrpc {
    async fn query(
        &self,
        req: Request<pb::QueryRequest>,
    ) -> Result<Response<pb::QueryResponse>, Status> {
        let r = req.into_inner();
        let hits = super::query(
            &self.state,
            QueryParams {
                motion: source("motion", r.motion)?,
                start_s: r.start_s,
                frames: r.frames as usize,
                k: r.k as usize,
                embedding: r.embedding,
                metric: r.metric,
                filters: r.filters.into_iter().collect(),
                exact: r.exact,
            },
        )
        .await?;
        Ok(Response::new(pb::QueryResponse {
            hits: hits
                .into_iter()
                .map(|h| pb::QueryHit {
                    motion_id: h.motion_id,
                    source_path: h.source_path,
                    start_frame: h.start_frame,
                    start_s: h.start_s,
                    score: h.score,
                    labels: h.labels.into_iter().collect(),
                })
                .collect(),
        }))
    }

    async fn interpolate(
        &self,
        req: Request<pb::InterpolateRequest>,
    ) -> Result<Response<pb::InterpolateResponse>, Status> {
        let r = req.into_inner();
        let (m, rep) = super::interpolate(
            &self.state,
            InterpolateParams {
                input: source("input", r.input)?,
                target: source("target", r.target)?,
                band: (r.band_lo as usize, r.band_hi as usize),
                objective: r.objective,
                steps: r.steps as usize,
                learning_rate: r.learning_rate,
                despike: r.despike,
            },
        )
        .await?;
        Ok(Response::new(pb::InterpolateResponse {
            output: Some(motion_pb(&m)),
            o_t: rep.similarity.o_t,
            i_o: rep.similarity.i_o,
            i_t: rep.similarity.i_t,
            jerk_input: rep.jitter.input,
            jerk_output: rep.jitter.output,
            jerk_target: rep.jitter.target,
            jerk_band_swap: rep.jitter.band_swap,
            loss: rep.loss,
            steps: rep.steps as u32,
            seconds: rep.seconds,
        }))
    }

    async fn lowpass(
        &self,
        req: Request<pb::LowpassRequest>,
    ) -> Result<Response<pb::LowpassResponse>, Status> {
        let r = req.into_inner();
        let m = super::lowpass(&self.state, source("motion", r.motion)?, r.cutoff as usize).await?;
        Ok(Response::new(pb::LowpassResponse {
            output: Some(motion_pb(&m)),
        }))
    }

    async fn keyframes(
        &self,
        req: Request<pb::KeyframesRequest>,
    ) -> Result<Response<pb::KeyframesResponse>, Status> {
        let r = req.into_inner();
        let (m, rep) = super::keyframes(
            &self.state,
            KeyframesParams {
                motion: source("motion", r.motion)?,
                count: r.count as usize,
                select: r.select,
                inbetween: r.inbetween,
                bpm: r.bpm,
                music: r.music.map(|f| (f.name, f.content)),
            },
        )
        .await?;
        Ok(Response::new(pb::KeyframesResponse {
            keyframes: rep.keyframes.iter().map(|&k| k as u32).collect(),
            mse: rep.mse,
            per_frame_error: rep.per_frame_error,
            output: Some(motion_pb(&m)),
        }))
    }

    async fn list_motions(
        &self,
        _req: Request<pb::ListMotionsRequest>,
    ) -> Result<Response<pb::ListMotionsResponse>, Status> {
        let rows = super::list_motions(&self.state).await?;
        Ok(Response::new(pb::ListMotionsResponse {
            motions: rows
                .into_iter()
                .map(|r| pb::MotionSummary {
                    id: r.id,
                    source_path: r.source_path,
                    format: r.format,
                    fps: r.fps,
                    frames: r.frames,
                    labels: r.labels.into_iter().collect(),
                })
                .collect(),
        }))
    }
}

/// The gRPC service with its message-size limit.
pub fn service(state: Arc<AppState>, max_message: usize) -> ChoreoServer<ChoreoGrpc> {
    ChoreoServer::new(ChoreoGrpc { state })
        .max_decoding_message_size(max_message)
        .max_encoding_message_size(max_message.max(64 << 20))
}
