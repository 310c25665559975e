//! gRPC over tonic (`proto/choreo/v1/choreo.proto`): every method converts
//! and calls the operation of [`super`].

use crate::motion::io::json::MotionParts;
use crate::service::interpolate::InterpolateParams;
use crate::service::keyframes::KeyframesParams;
use crate::service::query::QueryParams;
use crate::service::{self, ApiError, Choreo as Core};
use std::sync::Arc;
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status};

#[allow(clippy::all, missing_docs)]
pub mod pb {
    tonic::include_proto!("choreo.v1");
}

use crate::service::auth::Scope;
use pb::choreo_server::{Choreo, ChoreoServer};

mod convert;
pub use convert::motion_pb;
use convert::*;

/// The encoded descriptor set of `proto/choreo/v1`, served by reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("choreo_descriptor");

type FrameStream =
    std::pin::Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::GeneratedFrame, Status>> + Send>>;

pub struct ChoreoGrpc {
    pub state: Arc<Core>,
}

#[tonic::async_trait]
impl Choreo for ChoreoGrpc {
    type GenerateStreamStream = FrameStream;
    type DuetStream = FrameStream;

    async fn generate(
        &self,
        req: Request<pb::GenerateRequest>,
    ) -> Result<Response<pb::GenerateResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let p = generate_params(req.into_inner())?;
        let (m, r) = service::generate::generate(&self.state, p, &who).await?;
        Ok(Response::new(pb::GenerateResponse {
            output: Some(motion_pb(&m)),
            frames: r.frames as u32,
            seconds: r.seconds,
            real_time_factor: r.real_time_factor,
            exemplar: r.exemplar.map(|e| pb::Exemplar {
                source: e.source,
                start_s: e.start_s,
                seconds: e.seconds,
            }),
            chosen: r.chosen.map(|c| pb::ChosenCandidate {
                candidates: c.candidates as u32,
                index: c.index as u32,
                label_probability: c.label_probability,
                rank_every: c.rank_every,
            }),
            sampling: Some(pb::Sampling {
                temperature: r.sampling.temperature,
                top_k: r.sampling.top_k as u32,
                top_p: r.sampling.top_p,
                seed: r.sampling.seed,
                guidance: r.sampling.guidance,
                keep_near: r.sampling.keep_near,
                max_jump: r.sampling.max_jump,
                // As a request spells it: off is negative (0 asks for the
                // recommended pull).
                posture: if r.sampling.posture == 0.0 {
                    -1.0
                } else {
                    r.sampling.posture
                },
                context: r.sampling.context,
                draws: r.sampling.draws,
                pace: if r.sampling.pace == 0.0 {
                    -1.0
                } else {
                    r.sampling.pace
                },
                jerk: if r.sampling.jerk == 0.0 {
                    -1.0
                } else {
                    r.sampling.jerk
                },
                ease: if r.sampling.ease == 0.0 {
                    -1.0
                } else {
                    r.sampling.ease
                },
                matching: if r.sampling.matching == 0.0 {
                    -1.0
                } else {
                    r.sampling.matching
                },
                travel: if r.sampling.travel == 0.0 {
                    -1.0
                } else {
                    r.sampling.travel
                },
                skate: if r.sampling.skate == 0.0 {
                    -1.0
                } else {
                    r.sampling.skate
                },
            }),
        }))
    }

    async fn generate_stream(
        &self,
        req: Request<pb::GenerateRequest>,
    ) -> Result<Response<FrameStream>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let p = generate_params(req.into_inner())?;
        let (skeleton, fps) = service::generate::stream_format(&self.state)?;
        let rx = service::generate::generate_stream(&self.state, p, &who)
            .await?
            .frames;
        let out = tokio_stream::wrappers::ReceiverStream::new(rx).map(move |r| {
            r.map(|f| frame_pb(&f, &skeleton, fps))
                .map_err(Status::from)
        });
        Ok(Response::new(Box::pin(out)))
    }

    async fn duet(
        &self,
        req: Request<tonic::Streaming<pb::DuetRequest>>,
    ) -> Result<Response<FrameStream>, Status> {
        self.state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let mut inbound = req.into_inner();
        let first = inbound.message().await?.ok_or_else(|| {
            Status::invalid_argument("duet: the stream ended before its set-up message")
        })?;
        let (skeleton, fps) = service::generate::stream_format(&self.state)?;
        let labels = first.labels.clone().into_iter().collect();
        let session =
            service::duet::DuetSession::open(&self.state, &labels, &first.prompt_joints, {
                let n = named(&first.sampling);
                (sampling(first.sampling), n)
            })?;
        let (frames_in, frames_out) = service::duet::duet(session);
        tokio::spawn(async move {
            let mut pending = first.frame;
            loop {
                let frame = match pending.take() {
                    Some(f) => f,
                    None => match inbound.message().await {
                        Ok(Some(m)) => match m.frame {
                            Some(f) => f,
                            None => continue,
                        },
                        Ok(None) | Err(_) => break,
                    },
                };
                let motion = (|| {
                    service::input::motion_from_parts(
                        "frame",
                        MotionParts {
                            name: "duet".into(),
                            fps: frame.fps,
                            skeleton: frame.skeleton.clone(),
                            rotations: triples("frame.rotations", &frame.rotations)?,
                            translation: triples("frame.translation", &frame.translation)?,
                            labels: Default::default(),
                        },
                    )
                })();
                // A closed channel means the duet ended (an error, or the client left).
                if frames_in.send(motion).await.is_err() {
                    break;
                }
            }
        });
        let out = tokio_stream::wrappers::ReceiverStream::new(frames_out).map(move |r| {
            r.map(|f| frame_pb(&f, &skeleton, fps))
                .map_err(Status::from)
        });
        Ok(Response::new(Box::pin(out)))
    }

    async fn classify(
        &self,
        req: Request<pb::ClassifyRequest>,
    ) -> Result<Response<pb::ClassifyResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let r = req.into_inner();
        let c = service::classify::classify(&self.state, source("motion", r.motion)?, &who).await?;
        Ok(Response::new(pb::ClassifyResponse {
            classes: c
                .into_iter()
                .map(|(kind, v)| pb::KindScores {
                    kind,
                    label: v.first().map(|x| x.0.clone()).unwrap_or_default(),
                    scores: v
                        .into_iter()
                        .map(|(label, probability)| pb::ClassScore { label, probability })
                        .collect(),
                })
                .collect(),
        }))
    }

    async fn query(
        &self,
        req: Request<pb::QueryRequest>,
    ) -> Result<Response<pb::QueryResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let r = req.into_inner();
        let hits = service::query::query(
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
            &who,
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
                    video: h.video.unwrap_or_default(),
                    video_time_s: h.video_time_s.unwrap_or(0.0),
                })
                .collect(),
        }))
    }

    async fn interpolate(
        &self,
        req: Request<pb::InterpolateRequest>,
    ) -> Result<Response<pb::InterpolateResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let r = req.into_inner();
        let (m, rep) = service::interpolate::interpolate(
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
            &who,
        )
        .await?;
        #[allow(deprecated)]
        Ok(Response::new(pb::InterpolateResponse {
            output: Some(motion_pb(&m)),
            similarity: Some(pb::Similarity {
                o_t: rep.similarity.o_t,
                i_o: rep.similarity.i_o,
                i_t: rep.similarity.i_t,
            }),
            jitter: Some(pb::Jitter {
                input: rep.jitter.input,
                output: rep.jitter.output,
                target: rep.jitter.target,
                band_swap: rep.jitter.band_swap,
            }),
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
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let r = req.into_inner();
        let m = service::lowpass::lowpass(
            &self.state,
            source("motion", r.motion)?,
            r.cutoff as usize,
            &who,
        )
        .await?;
        Ok(Response::new(pb::LowpassResponse {
            output: Some(motion_pb(&m)),
        }))
    }

    async fn keyframes(
        &self,
        req: Request<pb::KeyframesRequest>,
    ) -> Result<Response<pb::KeyframesResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let r = req.into_inner();
        let (m, rep) = service::keyframes::keyframes(
            &self.state,
            KeyframesParams {
                motion: source("motion", r.motion)?,
                count: r.count as usize,
                select: r.select,
                inbetween: r.inbetween,
                bpm: r.bpm,
                music: r.music.map(|f| (f.name, f.content)),
            },
            &who,
        )
        .await?;
        Ok(Response::new(pb::KeyframesResponse {
            keyframes: rep.keyframes.iter().map(|&k| k as u32).collect(),
            mse: rep.mse,
            per_frame_error: rep.per_frame_error,
            output: Some(motion_pb(&m)),
            frames: rep.frames as u32,
            fps: rep.fps,
            select: rep.select.name().to_string(),
            inbetween: rep.inbetween,
            beat_alignment: rep.beat_alignment.map(|b| pb::BeatAlignment {
                original_music_to_motion: b.original_music_to_motion,
                rebuilt_music_to_motion: b.rebuilt_music_to_motion,
                original_motion_to_music: b.original_motion_to_music,
                rebuilt_motion_to_music: b.rebuilt_motion_to_music,
            }),
        }))
    }

    async fn list_motions(
        &self,
        req: Request<pb::ListMotionsRequest>,
    ) -> Result<Response<pb::ListMotionsResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let rows = service::motions::list_motions(&self.state, &who).await?;
        Ok(Response::new(pb::ListMotionsResponse {
            motions: rows.into_iter().map(summary_pb).collect(),
        }))
    }

    async fn ingest_motion(
        &self,
        req: Request<pb::IngestRequest>,
    ) -> Result<Response<pb::IngestResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Write, peer(&req))?;
        let actor = actor(&who, &req);
        let r = req.into_inner();
        if r.video.is_empty() && r.video_offset_s != 0.0 {
            return Err(ApiError::invalid("video_offset_s", "given without video").into());
        }
        let video = (!r.video.is_empty()).then(|| crate::store::VideoLink {
            video: r.video,
            video_offset_s: r.video_offset_s,
        });
        let stored = service::motions::ingest(
            &self.state,
            source("motion", r.motion)?,
            r.labels.into_iter().collect(),
            video,
            (!r.collection.is_empty()).then_some(r.collection),
            &who,
            &actor,
        )
        .await?;
        let merged_labels = stored
            .merged_labels
            .unwrap_or_default()
            .into_iter()
            .collect();
        Ok(Response::new(match stored.stored {
            service::motions::Stored::New { motion_id, windows } => pb::IngestResponse {
                motion_id,
                created: true,
                windows: windows as u32,
                merged_labels,
                status: "new".into(),
            },
            service::motions::Stored::Existing { motion_id } => pb::IngestResponse {
                motion_id,
                created: false,
                windows: 0,
                merged_labels,
                status: "existing".into(),
            },
        }))
    }

    async fn get_motion(
        &self,
        req: Request<pb::MotionId>,
    ) -> Result<Response<pb::GetMotionResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let (row, m) = service::motions::get_motion(&self.state, req.into_inner().id, &who).await?;
        Ok(Response::new(pb::GetMotionResponse {
            summary: Some(summary_pb(row)),
            motion: Some(motion_pb(&m)),
        }))
    }

    async fn export_motion(
        &self,
        req: Request<pb::MotionId>,
    ) -> Result<Response<pb::ExportMotionResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let bvh = service::motions::export_bvh(&self.state, req.into_inner().id, &who).await?;
        Ok(Response::new(pb::ExportMotionResponse { bvh }))
    }

    async fn delete_motion(
        &self,
        req: Request<pb::MotionId>,
    ) -> Result<Response<pb::DeleteMotionResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Write, peer(&req))?;
        let actor = actor(&who, &req);
        service::motions::delete_motion(&self.state, req.into_inner().id, &who, &actor).await?;
        Ok(Response::new(pb::DeleteMotionResponse {}))
    }

    async fn list_collections(
        &self,
        req: Request<pb::ListCollectionsRequest>,
    ) -> Result<Response<pb::ListCollectionsResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Read, peer(&req))?;
        let names = service::motions::list_collections(&self.state, &who).await?;
        Ok(Response::new(pb::ListCollectionsResponse { names }))
    }

    async fn create_collection(
        &self,
        req: Request<pb::CreateCollectionRequest>,
    ) -> Result<Response<pb::CreateCollectionResponse>, Status> {
        let who = self
            .state
            .authorize(bearer(&req), Scope::Admin, peer(&req))?;
        let actor = actor(&who, &req);
        let name = req.into_inner().name;
        let created = service::motions::create_collection(&self.state, &name, &actor).await?;
        Ok(Response::new(pb::CreateCollectionResponse { created }))
    }

    async fn list_audit(
        &self,
        req: Request<pb::ListAuditRequest>,
    ) -> Result<Response<pb::ListAuditResponse>, Status> {
        self.state
            .authorize(bearer(&req), Scope::Admin, peer(&req))?;
        let limit = match req.into_inner().limit {
            0 => 100,
            n => n,
        };
        let entries = service::motions::audit(&self.state, limit)
            .await?
            .into_iter()
            .map(|r| pb::AuditEntry {
                id: r.id,
                at: r.at,
                actor: r.actor,
                action: r.action,
                target: r.target,
                request_id: r.request_id,
            })
            .collect();
        Ok(Response::new(pb::ListAuditResponse { entries }))
    }
}

/// The gRPC service with its message-size limit.
pub fn service(state: Arc<Core>, max_message: usize) -> ChoreoServer<ChoreoGrpc> {
    ChoreoServer::new(ChoreoGrpc { state })
        .max_decoding_message_size(max_message)
        .max_encoding_message_size(max_message.max(64 << 20))
}
