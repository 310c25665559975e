//! Generate and stream: the language-model operations both transports
//! call (the live duet is [`super::duet`]), and what the model offers.

use super::{auth, ApiError, Choreo, MotionInput};
use crate::lm::model::{MotionGenerator, MotionModel};
use crate::lm::{forced_frames, prompt_slots, FrameDecoder, LmError, Sampling};
use crate::motion::{Labels, Motion};
use std::time::Instant;
use tokio::sync::mpsc;

/// Longest generation in one request, in frames (two minutes at 20 fps).
pub const MAX_GENERATE_FRAMES: usize = 2400;
/// Frames generated when the request names no length and no prompt.
pub const DEFAULT_GENERATE_FRAMES: usize = 100;

impl From<LmError> for ApiError {
    fn from(e: LmError) -> Self {
        match e {
            LmError::Invalid {
                file,
                field,
                reason,
            } => ApiError::Invalid {
                field,
                reason: if file == "request" {
                    reason
                } else {
                    format!("{file}: {reason}")
                },
            },
            other => ApiError::Internal(other.to_string()),
        }
    }
}

pub(crate) fn model(state: &Choreo) -> Result<MotionModel, ApiError> {
    state.model.clone().ok_or_else(|| {
        ApiError::Unavailable(
            "no model is loaded (start the server with --model DIR holding manifest.json and model.onnx)".into(),
        )
    })
}

/// A generation request as both transports give it.
pub struct GenerateParams {
    pub labels: Labels,
    /// Frames to generate (0 = the prompt's length, or 100).
    pub frames: usize,
    /// A motion whose `prompt_joints` are forced frame by frame.
    pub prompt: Option<MotionInput>,
    pub prompt_joints: Vec<String>,
    /// A motion the generation continues.
    pub seed_motion: Option<MotionInput>,
    pub sampling: Sampling,
    /// Which of `max_jump`, `top_p` and `posture` the request named; the
    /// others get the model's defaults for the label kinds asked for
    /// ([`MotionModel::fill_defaults`]).
    pub named: Named,
    /// `auto` or empty (a style exemplar of the labels seeds a generation
    /// that has labels and no seed motion), or `none`.
    pub exemplar: String,
    /// Best of N ([`crate::lm::best_of`]): one-shot generation makes this
    /// many clips and returns the one the model's class heads find likeliest
    /// to carry the labels; 0 or 1 = one clip. Streams take 1 only,
    /// unless steered.
    pub candidates: u32,
    /// Steering ([`crate::lm::steer`]): with more than one candidate, rank
    /// continuations of this many frames as the motion is made and go on
    /// from the best (streams too); 0 = rank whole clips.
    pub rank_every: u32,
    /// The root's ground path: `model` or empty (as the model's velocity
    /// tokens carry it) or `feet` (rebuilt from foot contact,
    /// [`crate::motion::contact`]).
    pub root: String,
    /// The legs: `model` or empty (as drawn) or `pin` (feet that touch the
    /// floor stay where they touched: [`crate::motion::foot_pin`]).
    pub feet: String,
}

/// The style exemplar a generation started from (context only, not in
/// the output).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ExemplarUsed {
    /// The training sequence it was cut from.
    pub source: String,
    pub start_s: f64,
    pub seconds: f64,
}

/// A generation ready to run: the generator and the forced slots.
pub struct GenerateJob {
    pub session: MotionModel,
    gen: Run,
    forced: Vec<Vec<Option<u32>>>,
    pub frames: usize,
    pub labels: Labels,
    pub exemplar: Option<ExemplarUsed>,
    /// Best of N: the sampling, and what candidates 1.. continue (their
    /// context tokens and exemplar; candidate 0 is `gen` / `exemplar`).
    sampling: Sampling,
    others: Vec<(Vec<u32>, Option<ExemplarUsed>)>,
    /// The root's ground path rebuilt from the feet.
    pub root_from_feet: bool,
    /// The feet pinned where they touch the floor.
    pub pin_feet: bool,
}

/// A job's running generation: plain (one clip, or the current
/// candidate of a best of N), or steered by the class heads every
/// `rank_every` frames.
enum Run {
    Plain(MotionGenerator),
    Steered(crate::lm::steer::Steered),
}

impl GenerateJob {
    /// The next frame's tokens.
    pub fn next(&mut self) -> Result<Vec<u32>, LmError> {
        let fl = self.session.vocabulary().frame_len();
        let forced = &self.forced;
        let forced_at = |f: usize| forced.get(f).cloned().unwrap_or_else(|| vec![None; fl]);
        match &mut self.gen {
            Run::Steered(g) => g.next_frame(&forced_at),
            Run::Plain(g) => g.next_frame(&forced_at(g.produced())),
        }
    }

    /// What steering kept, once frames are made.
    fn steered(&self) -> Option<ChosenCandidate> {
        match &self.gen {
            Run::Steered(g) => Some(ChosenCandidate {
                candidates: g.candidates(),
                index: g.kept(),
                label_probability: g.log_prob.exp(),
                rank_every: g.every() as u32,
            }),
            Run::Plain(_) => None,
        }
    }
}

pub use crate::lm::model::Named;

/// Validates a request and sets the generation up (cheap: no model step).
pub async fn generate_job(
    state: &Choreo,
    mut p: GenerateParams,
    who: &auth::Principal,
) -> Result<GenerateJob, ApiError> {
    let session = model(state)?;
    let vocab = session.vocabulary();
    session.fill_defaults(&p.labels, &mut p.sampling, p.named);
    if p.frames > MAX_GENERATE_FRAMES {
        return Err(ApiError::invalid(
            "frames",
            format!("{}; at most {MAX_GENERATE_FRAMES} per request", p.frames),
        ));
    }
    let root_from_feet = match p.root.as_str() {
        "" | "model" => false,
        "feet" => true,
        o => {
            return Err(ApiError::invalid(
                "root",
                format!("'{o}' is not model or feet"),
            ))
        }
    };
    let pin_feet = match p.feet.as_str() {
        "" | "model" => false,
        "pin" => {
            let sk = vocab.skeleton_def();
            if sk
                .as_ref()
                .and_then(|k| crate::motion::foot_pin::FootPin::new(k, vocab.fps))
                .is_none()
            {
                return Err(ApiError::invalid(
                    "feet",
                    format!("pin: the model's skeleton ({}) has no Left_Ankle / Right_Ankle legs to solve", vocab.skeleton),
                ));
            }
            true
        }
        o => {
            return Err(ApiError::invalid(
                "feet",
                format!("'{o}' is not model or pin"),
            ))
        }
    };
    let forced = match p.prompt {
        Some(input) => {
            if p.prompt_joints.is_empty() {
                return Err(ApiError::invalid(
                    "prompt_joints",
                    format!(
                        "a prompt needs the joints it fixes (any of: {})",
                        vocab.joints.join(", ")
                    ),
                ));
            }
            let m = state.resolve("prompt", input, who).await?;
            let slots = prompt_slots(vocab, &p.prompt_joints)?;
            let root_slot = 3 * vocab.joints.len();
            if root_from_feet && slots[root_slot] {
                return Err(ApiError::invalid(
                    "root",
                    format!(
                        "feet: the prompt fixes the root's path ({} is among prompt_joints); ask for root model to keep it",
                        vocab.joints[0]
                    ),
                ));
            }
            let tokens = vocab.encode_motion(&m)?;
            forced_frames(&tokens, &slots)
        }
        None => {
            if !p.prompt_joints.is_empty() {
                return Err(ApiError::invalid(
                    "prompt",
                    "prompt_joints given without a prompt motion",
                ));
            }
            Vec::new()
        }
    };
    let use_exemplar = match p.exemplar.as_str() {
        "" | "auto" => true,
        "none" => false,
        o => {
            return Err(ApiError::invalid(
                "exemplar",
                format!("'{o}' is not auto or none"),
            ))
        }
    };
    let (seed, exemplar) = match (p.seed_motion, &state.exemplars) {
        (Some(input), _) => (
            vocab.encode_motion(&state.resolve("seed_motion", input, who).await?)?,
            None,
        ),
        (None, Some(ex)) if use_exemplar => pick_exemplar(ex, &p.labels, p.sampling.seed),
        _ => (Vec::new(), None),
    };
    let frames = match (p.frames, forced.len()) {
        (0, 0) => DEFAULT_GENERATE_FRAMES,
        (0, n) => n.min(MAX_GENERATE_FRAMES),
        (n, _) => n,
    };
    let candidates = p.candidates.max(1);
    crate::lm::best_of::check(&session, &p.labels, candidates)?;
    // Best of N does N generations: the work a request may ask for is
    // bounded by frames × candidates, not frames alone.
    if candidates as usize * frames > MAX_GENERATE_FRAMES {
        return Err(ApiError::invalid(
            "candidates",
            format!(
                "{candidates} candidates × {frames} frames = {} frames of work; at most {MAX_GENERATE_FRAMES} per request",
                candidates as usize * frames
            ),
        ));
    }
    // Steering refuses one candidate, a round past its limit and labels
    // without a class head (`lm::steer::wanted`).
    if p.rank_every > 0 {
        let every = p.rank_every as usize;
        let steer = session.steered(&p.labels, &seed, p.sampling.clone(), (candidates, every))?;
        return Ok(GenerateJob {
            gen: Run::Steered(steer),
            session,
            forced,
            frames,
            labels: p.labels,
            exemplar,
            sampling: p.sampling,
            others: Vec::new(),
            root_from_feet,
            pin_feet,
        });
    }
    // Best of N: each candidate continues the exemplar its own seed picks
    // (candidate 0's is the one above), so the candidates differ more; a
    // seed motion is continued by all of them.
    let others = (1..candidates as usize)
        .map(|i| match (&state.exemplars, &exemplar) {
            (Some(ex), Some(_)) => pick_exemplar(
                ex,
                &p.labels,
                crate::lm::best_of::candidate_seed(p.sampling.seed, i),
            ),
            _ => (seed.clone(), None),
        })
        .collect();
    let gen = Run::Plain(session.generator(&p.labels, &seed, p.sampling.clone())?);
    Ok(GenerateJob {
        session,
        gen,
        forced,
        frames,
        labels: p.labels,
        exemplar,
        sampling: p.sampling,
        others,
        root_from_feet,
        pin_feet,
    })
}

/// The tokens of the style exemplar `seed` picks for `labels`, and what it is.
fn pick_exemplar(
    ex: &crate::lm::exemplars::Exemplars,
    labels: &Labels,
    seed: u64,
) -> (Vec<u32>, Option<ExemplarUsed>) {
    match ex.pick(labels, seed) {
        Some((e, tokens)) => (
            tokens.to_vec(),
            Some(ExemplarUsed {
                source: e.source.clone(),
                start_s: e.start_frame as f64 / ex.fps,
                seconds: e.frames as f64 / ex.fps,
            }),
        ),
        None => (Vec::new(), None),
    }
}

/// What a generation measured.
#[derive(Clone, Debug)]
pub struct GenerateReport {
    pub frames: usize,
    pub seconds: f64,
    /// Motion seconds produced per wall-clock second.
    pub real_time_factor: f64,
    /// The style exemplar it started from, if any.
    pub exemplar: Option<ExemplarUsed>,
    /// Best of N, when more than one candidate was made.
    pub chosen: Option<ChosenCandidate>,
    /// The sampling the generation ran with, defaults filled in.
    pub sampling: Sampling,
}

/// Which of several candidates a best-of-N generation returned.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ChosenCandidate {
    pub candidates: usize,
    /// Its index; it was sampled with seed `lm::best_of::candidate_seed(seed, index)`.
    pub index: usize,
    /// The probability the model's class heads give it of the asked-for
    /// labels (their product, over the kinds the heads classify).
    pub label_probability: f64,
    /// 0: whole clips were ranked. Else steered: continuations of this
    /// many frames were ranked as the motion was made, and `index` is the
    /// one kept in the last round.
    pub rank_every: u32,
}

/// One-shot generation: every frame, decoded into one motion (SMPL-13 at
/// the model's frame rate).
pub async fn generate(
    state: &Choreo,
    p: GenerateParams,
    who: &auth::Principal,
) -> Result<(Motion, GenerateReport), ApiError> {
    let mut job = generate_job(state, p, who).await?;
    state
        .heavy("generate", move || {
            let t0 = Instant::now();
            let model = job.session.clone();
            let (all, chosen) = if matches!(job.gen, Run::Steered(..)) {
                let mut all = Vec::with_capacity(job.frames * model.vocabulary().frame_len());
                for _ in 0..job.frames {
                    all.extend(job.next()?);
                }
                (all, job.steered())
            } else {
                let (labels, n) = (job.labels.clone(), 1 + job.others.len() as u32);
                let choice = crate::lm::best_of::best_of(&model, &labels, n, |i| {
                    if i > 0 {
                        let mut s = job.sampling.clone();
                        s.seed = crate::lm::best_of::candidate_seed(s.seed, i);
                        job.gen = Run::Plain(model.generator(&labels, &job.others[i - 1].0, s)?);
                    }
                    let mut all = Vec::with_capacity(job.frames * model.vocabulary().frame_len());
                    for _ in 0..job.frames {
                        all.extend(job.next()?);
                    }
                    Ok(all)
                })?;
                if choice.index > 0 {
                    job.exemplar = job.others[choice.index - 1].1.clone();
                }
                let chosen = (choice.candidates > 1).then(|| ChosenCandidate {
                    candidates: choice.candidates,
                    index: choice.index,
                    label_probability: choice.log_prob.exp(),
                    rank_every: 0,
                });
                (choice.tokens, chosen)
            };
            let vocab = job.session.vocabulary();
            let mut m = vocab.decode_motion(&all, "generated")?;
            if job.root_from_feet {
                m = crate::motion::contact::lock_feet(&m);
            }
            if job.pin_feet {
                m = crate::motion::foot_pin::pin_feet(&m);
            }
            m.labels = job.labels.clone();
            let secs = t0.elapsed().as_secs_f64();
            let report = GenerateReport {
                frames: job.frames,
                seconds: secs,
                real_time_factor: job.frames as f64 / vocab.fps / secs.max(1e-9),
                exemplar: job.exemplar.clone(),
                chosen,
                sampling: job.sampling.clone(),
            };
            Ok((m, report))
        })
        .await
}

/// One streamed frame.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamFrame {
    pub index: usize,
    /// Local axis-angle per joint of the model's skeleton.
    pub rotations: Vec<[f64; 3]>,
    pub translation: [f64; 3],
    /// Time spent producing this frame, ms.
    pub latency_ms: f64,
}

/// The model's skeleton and frame rate, for streamed frames.
pub fn stream_format(state: &Choreo) -> Result<(String, f64), ApiError> {
    let s = model(state)?;
    let v = s.vocabulary();
    Ok((v.skeleton.clone(), v.fps))
}

/// Streaming generation: frames arrive on the channel as soon as each is
/// decoded. The worker holds a permit and stops when the receiver is
/// dropped (the client went away).
/// A started stream: the style exemplar it starts from, if any, and its
/// frames.
pub struct FrameStream {
    pub exemplar: Option<ExemplarUsed>,
    /// The sampling it runs with, defaults filled in.
    pub sampling: Sampling,
    pub frames: mpsc::Receiver<Result<StreamFrame, ApiError>>,
}

pub async fn generate_stream(
    state: &Choreo,
    p: GenerateParams,
    who: &auth::Principal,
) -> Result<FrameStream, ApiError> {
    if p.candidates > 1 && p.rank_every == 0 {
        return Err(ApiError::invalid(
            "candidates",
            format!(
                "{}: a stream sends each frame as it is made, so it cannot choose among whole clips (want 1, steer with rank_every, or use the one-shot generate)",
                p.candidates
            ),
        ));
    }
    let mut job = generate_job(state, p, who).await?;
    let exemplar = job.exemplar.clone();
    let sampling = job.sampling.clone();
    let permit = state
        .workers
        .clone()
        .try_acquire_owned()
        .map_err(|_| ApiError::Busy("every worker is busy; retry generate later".into()))?;
    let mut dec = FrameDecoder::new();
    if job.root_from_feet {
        dec = dec.root_from_feet(job.session.vocabulary())?;
    }
    if job.pin_feet {
        dec = dec.pin_feet(job.session.vocabulary())?;
    }
    let (tx, rx) = mpsc::channel(64);
    tokio::task::spawn_blocking(move || {
        let _p = permit;
        for index in 0..job.frames {
            let t0 = Instant::now();
            let out = job
                .next()
                .and_then(|tokens| dec.decode(job.session.vocabulary(), &tokens));
            let msg = out
                .map_err(ApiError::from)
                .map(|(rotations, translation)| StreamFrame {
                    index,
                    rotations,
                    translation,
                    latency_ms: t0.elapsed().as_secs_f64() * 1e3,
                });
            let failed = msg.is_err();
            if tx.blocking_send(msg).is_err() || failed {
                break;
            }
        }
    });
    Ok(FrameStream {
        exemplar,
        sampling,
        frames: rx,
    })
}

/// What the loaded model offers a client (`GET /v1/model`): its kind, frame
/// rate, skeleton (joint names in frame order, parents, rest offsets),
/// the joints a prompt may force, the label values it was trained on, its
/// context, the longest generation a request may ask for, and whether it
/// can hold the labels' postures (`sampling.posture`).
pub fn model_info(state: &Choreo) -> Result<serde_json::Value, ApiError> {
    let s = model(state)?;
    let v = s.vocabulary();
    let skeleton = v.skeleton_def().map(|k| skeleton_json(&k));
    Ok(serde_json::json!({
        "kind": s.kind(),
        "fps": v.fps,
        "skeleton": skeleton,
        "prompt_joints": v.joints,
        "labels": v.labels,
        "conditioned_on": s.cond_kinds(),
        "context_frames": s.context_frames(),
        "max_frames": MAX_GENERATE_FRAMES,
        "inbetweener": state.inbetweener.is_some(),
        "postures": s.has_postures(),
    }))
}

/// A skeleton as JSON: `{kind, names, parents (null for the root), offsets
/// (metres, each in its parent's frame; the root's is its rest position)}`.
/// Forward kinematics with these gives the server's joint positions.
pub fn skeleton_json(k: &crate::motion::Skeleton) -> serde_json::Value {
    serde_json::json!({
        "kind": k.kind,
        "names": k.names,
        "parents": k.parents,
        "offsets": k.offsets,
    })
}
