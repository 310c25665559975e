//! The gRPC wire types to and from the application's: motion sources,
//! motions, sampling, generated frames, summaries, errors (as `Status`
//! with `retry-after`), and what a request carries (caller address,
//! bearer token, request id).

use super::pb;
use crate::motion::io::json::MotionParts;
use crate::motion::Motion;
use crate::service::auth::Principal;
use crate::service::{ApiError, MotionInput};
use tonic::{Request, Status};

impl From<ApiError> for Status {
    fn from(e: ApiError) -> Status {
        let mut st = Status::new(e.grpc_code(), e.to_string());
        // The REST answer's Retry-After, as metadata.
        let retry = match &e {
            ApiError::RateLimited { retry_after_s, .. } => Some(*retry_after_s),
            ApiError::Busy(_) => Some(1),
            _ => None,
        };
        if let Some(secs) = retry {
            st.metadata_mut().insert("retry-after", secs.into());
        }
        st
    }
}

pub(super) fn triples(field: &str, v: &[f64]) -> Result<Vec<[f64; 3]>, ApiError> {
    if v.len() % 3 != 0 {
        return Err(ApiError::invalid(
            field,
            format!("{} values is not a multiple of 3", v.len()),
        ));
    }
    Ok(v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect())
}

pub(super) fn source(field: &str, s: Option<pb::MotionSource>) -> Result<MotionInput, ApiError> {
    match s.and_then(|s| s.source) {
        Some(pb::motion_source::Source::Motion(m)) => Ok(MotionInput::Inline(
            crate::service::input::motion_from_parts(
                &format!("{field}.motion"),
                MotionParts {
                    rotations: triples(&format!("{field}.motion.rotations"), &m.rotations)?,
                    translation: triples(&format!("{field}.motion.translation"), &m.translation)?,
                    name: m.name,
                    fps: m.fps,
                    skeleton: m.skeleton,
                    labels: m.labels.into_iter().collect(),
                },
            )?,
        )),
        Some(pb::motion_source::Source::File(f)) => Ok(MotionInput::File {
            read: crate::service::input::read_options(
                &format!("{field}.file"),
                (!f.keypoints.is_empty()).then_some(f.keypoints.as_str()),
                (f.fps != 0.0).then_some(f.fps),
                (!f.up.is_empty()).then_some(f.up.as_str()),
                (f.min_confidence != 0.0).then_some(f.min_confidence),
                f.smooth_s_set.then_some(f.smooth_s),
            )?,
            name: f.name,
            bytes: f.content,
        }),
        Some(pb::motion_source::Source::Id(id)) => Ok(MotionInput::Stored(id)),
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

/// Which of `max_jump`, `top_p`, `posture` and `draws` a request named (proto3: 0
/// = not named; an explicit setting, any of temperature, top_k, top_p or
/// keep_near set, names its top_p, 0 there meaning no cut).
pub(super) fn named(s: &Option<pb::Sampling>) -> crate::service::generate::Named {
    let d = pb::Sampling::default();
    let s = s.as_ref().unwrap_or(&d);
    crate::service::generate::Named {
        max_jump: s.max_jump != 0,
        top_p: explicit(s),
        posture: s.posture != 0.0,
        draws: s.draws != 0,
        pace: s.pace != 0.0,
        jerk: s.jerk != 0.0,
        ease: s.ease != 0.0,
        matching: s.matching != 0.0,
        skate: s.skate != 0.0,
    }
}

/// Whether a sampling message sets any of temperature, top_k, top_p or
/// keep_near: an explicit setting; else the recommended one.
fn explicit(s: &pb::Sampling) -> bool {
    s.temperature != 0.0 || s.top_k != 0 || s.top_p != 0.0 || s.keep_near != 0
}

/// A request's sampling; none named (absent, or only a seed) = the
/// recommended setting, as over REST.
pub(super) fn sampling(s: Option<pb::Sampling>) -> crate::lm::Sampling {
    let s = s.unwrap_or_default();
    let r = crate::lm::Sampling::recommended(s.seed);
    let guidance = if s.guidance == 0.0 {
        r.guidance
    } else {
        s.guidance
    };
    // proto3 cannot tell 0 from absent: 0 = the recommended limit, and
    // 180 (half a turn) already allows every move.
    let max_jump = if s.max_jump == 0 {
        r.max_jump
    } else {
        s.max_jump
    };
    // proto3 again: 0 = the recommended pull, negative = none.
    let posture = if s.posture == 0.0 {
        r.posture
    } else {
        s.posture.max(0.0)
    };
    // 0 = the recommended count of candidate frames.
    let draws = if s.draws == 0 { r.draws } else { s.draws };
    // proto3 again: 0 = the model's default hold, negative = none.
    let pace = if s.pace == 0.0 {
        r.pace
    } else {
        s.pace.max(0.0)
    };
    // proto3 again: 0 = the model's default price, negative = none.
    let jerk = if s.jerk == 0.0 {
        r.jerk
    } else {
        s.jerk.max(0.0)
    };
    // proto3 again: 0 = the model's default ease, negative = none.
    let ease = if s.ease == 0.0 {
        r.ease
    } else {
        s.ease.max(0.0)
    };
    // proto3 again: 0 = the model's default, negative = none.
    let matching = if s.matching == 0.0 {
        r.matching
    } else {
        s.matching.max(0.0)
    };
    // proto3 again: 0 = as strongly as the joints, negative = none.
    let travel = if s.travel == 0.0 {
        r.travel
    } else {
        s.travel.max(0.0)
    };
    // proto3 again: 0 = the model's default price, negative = none.
    let skate = if s.skate == 0.0 {
        r.skate
    } else {
        s.skate.max(0.0)
    };
    if !explicit(&s) {
        return crate::lm::Sampling {
            guidance,
            max_jump,
            posture,
            context: s.context,
            draws,
            pace,
            jerk,
            ease,
            matching,
            travel,
            skate,
            ..r
        };
    }
    crate::lm::Sampling {
        temperature: s.temperature,
        top_k: s.top_k as usize,
        top_p: if s.top_p == 0.0 { 1.0 } else { s.top_p },
        seed: s.seed,
        guidance,
        keep_near: s.keep_near,
        max_jump,
        posture,
        context: s.context,
        draws,
        pace,
        jerk,
        ease,
        matching,
        travel,
        skate,
    }
}

pub(super) fn generate_params(
    r: pb::GenerateRequest,
) -> Result<crate::service::generate::GenerateParams, ApiError> {
    Ok(crate::service::generate::GenerateParams {
        labels: r.labels.into_iter().collect(),
        frames: r.frames as usize,
        prompt: r.prompt.map(|p| source("prompt", Some(p))).transpose()?,
        prompt_joints: r.prompt_joints,
        seed_motion: r
            .seed_motion
            .map(|p| source("seed_motion", Some(p)))
            .transpose()?,
        named: named(&r.sampling),
        sampling: sampling(r.sampling),
        exemplar: r.exemplar,
        candidates: r.candidates,
        rank_every: r.rank_every,
        root: r.root,
        feet: r.feet,
    })
}

pub(super) fn frame_pb(
    f: &crate::service::generate::StreamFrame,
    skeleton: &str,
    fps: f64,
) -> pb::GeneratedFrame {
    pb::GeneratedFrame {
        index: f.index as u32,
        rotations: f.rotations.iter().flat_map(|r| r.iter().copied()).collect(),
        translation: f.translation.to_vec(),
        latency_ms: f.latency_ms,
        skeleton: skeleton.to_string(),
        fps,
    }
}

/// The caller's address (the anonymous caller's rate-limit key).
pub(super) fn peer<T>(req: &Request<T>) -> Option<std::net::IpAddr> {
    req.remote_addr().map(|a| a.ip())
}

/// The writer of a request and its id (`x-request-id`, set by the metrics
/// layer when the caller sent none).
pub(super) fn actor<T>(who: &Principal, req: &Request<T>) -> crate::service::motions::Actor {
    crate::service::motions::Actor {
        name: who.name.clone(),
        request_id: req
            .metadata()
            .get(crate::service::metrics::REQUEST_ID)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string(),
    }
}

pub(super) fn bearer<T>(req: &Request<T>) -> Option<&str> {
    req.metadata()
        .get("authorization")
        .and_then(|v| v.to_str().ok())
}

pub(super) fn summary_pb(r: crate::store::MotionRow) -> pb::MotionSummary {
    pb::MotionSummary {
        id: r.id,
        source_path: crate::service::query::public_source(&r.source_path),
        format: r.format,
        fps: r.fps,
        frames: r.frames,
        labels: r.labels.into_iter().collect(),
        joints: r.joints,
        skeleton: r.skeleton,
        duration_s: r.duration_s,
        video_offset_s: r.video.as_ref().map_or(0.0, |v| v.video_offset_s),
        video: r.video.map(|v| v.video).unwrap_or_default(),
        collection: r.collection,
    }
}
