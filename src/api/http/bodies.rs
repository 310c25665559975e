//! The REST request bodies as JSON: each refuses fields it does not know
//! (named in the error), and turns into the transport-neutral parameters.

use super::MotionJson;
use crate::motion::Labels;
use crate::service::{self, ApiError, MotionInput};
use base64::Engine;
use serde::Deserialize;

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

pub(super) fn source(field: &str, s: Option<SourceJson>) -> Result<MotionInput, ApiError> {
    let s = s.ok_or_else(|| ApiError::invalid(field, "missing"))?;
    match (s.motion, s.file, s.id) {
        (None, None, Some(id)) => Ok(MotionInput::Stored(id)),
        (Some(m), None, None) => {
            let at = format!("{field}.motion");
            Ok(MotionInput::Inline(service::input::motion_from_parts(
                &at,
                m.into_parts(&at)?,
            )?))
        }
        (None, Some(f), None) => {
            let bytes = base64::engine::general_purpose::STANDARD
                .decode(f.content_base64.as_bytes())
                .map_err(|e| {
                    ApiError::invalid(format!("{field}.file.content_base64"), e.to_string())
                })?;
            Ok(MotionInput::File {
                read: service::input::read_options(
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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LowpassBody {
    pub motion: Option<SourceJson>,
    pub cutoff: usize,
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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AuditQuery {
    #[serde(default = "default_audit_limit")]
    pub limit: i64,
}

pub(super) fn default_audit_limit() -> i64 {
    100
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectionBody {
    pub name: String,
}

/// Sampling settings as JSON, all optional. Without a temperature the
/// request gets the recommended setting (`lm::sampling::RECOMMENDED`), with
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
    /// Changes of at most this many bins never cut by top_k / top_p
    /// (frame model); absent = 2 with the recommended setting, 0 with an
    /// explicit temperature.
    pub keep_near: Option<u32>,
    /// No slot moves more than this many bins a frame (frame model);
    /// absent = the model's default for the label kinds asked for
    /// (`MotionModel::default_max_jump`), 0 = no limit.
    pub max_jump: Option<u32>,
    /// The pull toward the labels' postures (frame model; 0 = off);
    /// absent = the recommended value.
    pub posture: Option<f64>,
    /// Frames of history the frame model reads (0 or absent = its whole
    /// window).
    pub context: Option<u32>,
    /// Candidate frames drawn for each frame, the one most typical of the
    /// model kept (frame model; 1 = plain drawing); absent = the
    /// model's default for the label kinds asked for (its manifest's
    /// `sampling_by_kind`), else the recommended count (1), with or
    /// without a temperature.
    pub draws: Option<u32>,
    /// How strongly the kept candidate holds the pace of the motion the
    /// clip continues (a seed motion or a style exemplar; frame model,
    /// with `draws` 2 or more; 0 = off); absent = the model's default for
    /// the label kinds asked for where `draws` leaves a choice, else off.
    pub pace: Option<f64>,
    /// How strongly the kept candidate avoids jerk (the change of each
    /// joint angle's acceleration; frame model, with `draws` 2 or more;
    /// 0 = off); absent = the model's default for the label kinds asked
    /// for where `draws` leaves a choice, else off.
    pub jerk: Option<f64>,
    /// How far the posture pull eases off while the clip moves slower
    /// than the motion it continues (frame model, with a posture pull;
    /// the pull times min(1, pace ratio)^ease; 0 = off); absent = the
    /// model's default for the label kinds asked for where there is a
    /// pull, else off.
    pub ease: Option<f64>,
    /// How strongly each joint, and the root's ground velocity, follow the
    /// asked-for labels' real takes (motion matching: the nearest real
    /// frame's successor as a target; frame model, with labels; the
    /// posture pull then holds only the body's tilt; 0 = off); absent = the
    /// model's default for the label kinds asked for (the bundled model: 6
    /// for a style or a content) where the model
    /// has real takes of every asked-for label, else off.
    pub matching: Option<f64>,
    /// With `matching`: how strongly the root's ground velocity follows
    /// the matched take's travel, as a share of the joints' pull (1 = as
    /// strongly, the default; 0 = the root's travel left to the model
    /// while the joints still follow the takes).
    pub travel: Option<f64>,
    /// How strongly the kept candidate keeps planted feet still (the
    /// ground speed, m/s, of the ankles on the floor in the frame before
    /// and in it;
    /// frame model, with `draws` 2 or more; 0 = off); absent = the model's
    /// default for the label kinds asked for where `draws` leaves a
    /// choice, else off.
    pub skate: Option<f64>,
}

impl SamplingJson {
    /// Which of `max_jump`, `top_p` and `posture` the request named; an
    /// explicit temperature names top_p too (absent there = no cut).
    pub fn named(&self) -> crate::service::generate::Named {
        crate::service::generate::Named {
            max_jump: self.max_jump.is_some(),
            top_p: self.top_p.is_some() || self.temperature.is_some(),
            posture: self.posture.is_some(),
            draws: self.draws.is_some(),
            pace: self.pace.is_some(),
            jerk: self.jerk.is_some(),
            ease: self.ease.is_some(),
            matching: self.matching.is_some(),
            skate: self.skate.is_some(),
        }
    }

    /// `top_p` 0 means all (no nucleus cut), as over gRPC, whose proto3
    /// field cannot tell 0 from absent.
    pub fn to_sampling(&self) -> crate::lm::Sampling {
        let r = crate::lm::Sampling::recommended(self.seed);
        let top_p = self.top_p.map(|p| if p == 0.0 { 1.0 } else { p });
        let guidance = self.guidance.unwrap_or(r.guidance);
        match self.temperature {
            None => crate::lm::Sampling {
                top_k: self.top_k.unwrap_or(r.top_k),
                top_p: top_p.unwrap_or(r.top_p),
                guidance,
                keep_near: self.keep_near.unwrap_or(r.keep_near),
                max_jump: self.max_jump.unwrap_or(r.max_jump),
                posture: self.posture.unwrap_or(r.posture),
                context: self.context.unwrap_or(r.context),
                draws: self.draws.unwrap_or(r.draws),
                pace: self.pace.unwrap_or(r.pace),
                jerk: self.jerk.unwrap_or(r.jerk),
                ease: self.ease.unwrap_or(r.ease),
                matching: self.matching.unwrap_or(r.matching),
                travel: self.travel.unwrap_or(r.travel),
                skate: self.skate.unwrap_or(r.skate),
                ..r
            },
            Some(t) => crate::lm::Sampling {
                temperature: t,
                top_k: self.top_k.unwrap_or(0),
                top_p: top_p.unwrap_or(1.0),
                seed: self.seed,
                guidance,
                keep_near: self.keep_near.unwrap_or(0),
                max_jump: self.max_jump.unwrap_or(r.max_jump),
                posture: self.posture.unwrap_or(r.posture),
                context: self.context.unwrap_or(r.context),
                draws: self.draws.unwrap_or(r.draws),
                pace: self.pace.unwrap_or(r.pace),
                jerk: self.jerk.unwrap_or(r.jerk),
                ease: self.ease.unwrap_or(r.ease),
                matching: self.matching.unwrap_or(r.matching),
                travel: self.travel.unwrap_or(r.travel),
                skate: self.skate.unwrap_or(r.skate),
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
    /// `auto` (the default) or `none`.
    #[serde(default)]
    pub exemplar: String,
    /// Best of N (one-shot only; absent = 1), or with `rank_every`
    /// candidates per steering round.
    #[serde(default)]
    pub candidates: u32,
    /// Steering: rank continuations of this many frames as the motion is
    /// made (absent or 0 = rank whole clips).
    #[serde(default)]
    pub rank_every: u32,
    /// The root's ground path: `model` (the default) or `feet`.
    #[serde(default)]
    pub root: String,
    /// The legs: `model` (the default) or `pin` (feet that touch the floor
    /// stay there; leg IK).
    #[serde(default)]
    pub feet: String,
}

impl GenerateBody {
    /// The request both REST and the WebSocket stream take.
    pub(crate) fn params(self) -> Result<service::generate::GenerateParams, ApiError> {
        Ok(service::generate::GenerateParams {
            labels: self.labels,
            frames: self.frames,
            prompt: self.prompt.map(|x| source("prompt", Some(x))).transpose()?,
            prompt_joints: self.prompt_joints,
            seed_motion: self
                .seed_motion
                .map(|x| source("seed_motion", Some(x)))
                .transpose()?,
            sampling: self.sampling.to_sampling(),
            named: self.sampling.named(),
            exemplar: self.exemplar,
            candidates: self.candidates,
            rank_every: self.rank_every,
            root: self.root,
            feet: self.feet,
        })
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassifyBody {
    pub motion: Option<SourceJson>,
}
