//! One handle over both kinds of motion model, chosen by the manifest's
//! `kind`: the thesis's flat GPT (`motion-lm`, 43 steps a frame) and the
//! frame model (`motion-frame-lm`, one global step and a small local
//! decoder a frame). Generation, streaming, duet and classification go
//! through it, so callers never ask which kind they hold.

use super::engine::Engine;
use super::frame::FRAME_KIND;
use super::frame_runtime::{FrameGenerator, FrameSession};
use super::generate::{
    add_softmax, class_table, classify as flat_classify, classify_starts, Generator,
};
use super::manifest::read_manifest;
use super::sampling::Sampling;
use super::{LmError, LmSession};
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use std::path::Path;
use std::sync::Arc;

/// Which sampling fields a request named (the others take the model's
/// per-kind defaults, [`MotionModel::fill_defaults`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Named {
    pub max_jump: bool,
    pub top_p: bool,
    pub posture: bool,
    pub draws: bool,
    pub pace: bool,
    pub jerk: bool,
    pub ease: bool,
    pub matching: bool,
    pub skate: bool,
}

/// A loaded motion model of either kind: immutable, shared by requests.
#[derive(Clone)]
pub enum MotionModel {
    Flat(Arc<LmSession>),
    Frame(Arc<FrameSession>),
}

/// Class probabilities per kind, each sorted by probability.
pub type ClassTable = Vec<(String, Vec<(String, f64)>)>;

impl MotionModel {
    /// Loads a model folder (or its manifest) of either kind.
    pub fn load(path: &Path) -> Result<MotionModel, LmError> {
        MotionModel::load_with(path, &Engine::tract())
    }

    /// The exemplars beside the model at `path`: a frame model's, loaded
    /// with its session (they are what `sampling.matching` follows), else
    /// read from the folder.
    pub fn exemplars(
        &self,
        path: &Path,
    ) -> Result<Option<Arc<super::exemplars::Exemplars>>, LmError> {
        match self {
            MotionModel::Frame(s) => Ok(s.exemplars.clone()),
            MotionModel::Flat(_) => {
                Ok(super::exemplars::Exemplars::load(path, self.vocabulary())?.map(Arc::new))
            }
        }
    }

    /// Loads it on `engine`'s runtime.
    pub fn load_with(path: &Path, engine: &Engine) -> Result<MotionModel, LmError> {
        let (_, name, v): (_, String, serde_json::Value) = read_manifest(path)?;
        match v.get("kind").and_then(|k| k.as_str()) {
            Some("motion-lm") => Ok(MotionModel::Flat(Arc::new(LmSession::load_with(
                path, engine,
            )?))),
            Some(k) if k == FRAME_KIND => Ok(MotionModel::Frame(Arc::new(
                FrameSession::load_with(path, engine)?,
            ))),
            other => Err(LmError::invalid(
                name,
                "kind",
                format!("{other:?}: this build loads \"motion-lm\" and \"{FRAME_KIND}\" models"),
            )),
        }
    }

    /// `motion-lm` or `motion-frame-lm`.
    pub fn kind(&self) -> &'static str {
        match self {
            MotionModel::Flat(_) => "motion-lm",
            MotionModel::Frame(_) => FRAME_KIND,
        }
    }

    pub fn vocabulary(&self) -> &Vocabulary {
        match self {
            MotionModel::Flat(s) => &s.manifest.vocabulary,
            MotionModel::Frame(s) => &s.manifest.vocabulary,
        }
    }

    /// Frames of context the model sees.
    pub fn context_frames(&self) -> usize {
        match self {
            MotionModel::Flat(s) => s.config().max_frames,
            MotionModel::Frame(s) => s.config().max_frames,
        }
    }

    /// Label kinds the model is conditioned on.
    pub fn cond_kinds(&self) -> &[String] {
        match self {
            MotionModel::Flat(s) => &s.config().cond_kinds,
            MotionModel::Frame(s) => &s.config().cond_kinds,
        }
    }

    /// Fills in what a request for these labels did not name of
    /// `max_jump`, `top_p`, `posture`, `draws`, `pace`, `jerk`, `ease` and
    /// `matching`: the model's defaults for their kinds
    /// ([`Self::fill_kind_defaults`], which `choreo eval generate
    /// --sampling default` goes through too, so what is measured as the
    /// default is what a request naming no sampling gets).
    ///
    /// A default `matching` (one the request did not name) applies only
    /// where the model has real takes of every asked-for label to follow
    /// ([`super::matching::Library::available`]); elsewhere (labels of two
    /// corpora, a model folder without exemplars.json) the request runs
    /// without it, as the answer's sampling then says, where naming it
    /// would be a 400.
    pub fn fill_defaults(&self, labels: &Labels, s: &mut Sampling, named: Named) {
        self.fill_kind_defaults(labels.keys(), s, named);
        if !named.matching && s.matching > 0.0 && !self.can_match(labels) {
            s.matching = 0.0;
        }
    }

    /// Whether `sampling.matching` can follow real takes of `labels`: a
    /// frame model whose exemplars hold a span of 3 frames or more
    /// carrying every one of them.
    pub fn can_match(&self, labels: &Labels) -> bool {
        match self {
            MotionModel::Flat(_) => false,
            MotionModel::Frame(f) => f.exemplars.as_deref().is_some_and(|ex| {
                super::matching::Library::available(ex, labels, f.config().slots)
            }),
        }
    }

    /// [`Self::fill_defaults`] for label kinds alone (`choreo eval generate
    /// --sampling default`, which asks for every value of one kind): a
    /// default `matching` stays, and a value without real takes to follow
    /// is then a clear error.
    pub fn fill_kind_defaults<'a, I>(&self, kinds: I, s: &mut Sampling, named: Named)
    where
        I: IntoIterator<Item = &'a String> + Clone,
    {
        if !named.max_jump {
            s.max_jump = self.default_max_jump(kinds.clone());
        }
        let d = self.kind_sampling(kinds);
        if let (false, Some(p)) = (named.top_p, d.top_p) {
            s.top_p = p;
        }
        if let (false, Some(w)) = (named.posture, d.posture) {
            s.posture = w;
        }
        if let (false, Some(n)) = (named.draws, d.draws) {
            s.draws = n;
        }
        // The pace hold chooses among candidates: a default one only where
        // there are some to choose among.
        if let (false, Some(a)) = (named.pace, d.pace) {
            if s.draws > 1 {
                s.pace = a;
            }
        }
        if let (false, Some(a)) = (named.jerk, d.jerk) {
            if s.draws > 1 {
                s.jerk = a;
            }
        }
        if let (false, Some(a)) = (named.skate, d.skate) {
            if s.draws > 1 {
                s.skate = a;
            }
        }
        // The ease loosens a pull: a default one only where there is one.
        if let (false, Some(a)) = (named.ease, d.ease) {
            if s.posture > 0.0 {
                s.ease = a;
            }
        }
        if let (false, Some(a)) = (named.matching, d.matching) {
            s.matching = a;
        }
    }

    /// The `top_p`, `posture`, `draws`, `pace` and `jerk` defaults for a request asking for these
    /// label kinds and naming them not: per field, the first kind (in the
    /// order given) the manifest's `sampling_by_kind` lists it for.
    pub fn kind_sampling<'a>(
        &self,
        kinds: impl IntoIterator<Item = &'a String>,
    ) -> super::frame::KindSampling {
        let mut out = super::frame::KindSampling::default();
        if let MotionModel::Frame(s) = self {
            for d in kinds
                .into_iter()
                .filter_map(|k| s.manifest.sampling_by_kind.get(k))
            {
                out.top_p = out.top_p.or(d.top_p);
                out.posture = out.posture.or(d.posture);
                out.draws = out.draws.or(d.draws);
                out.pace = out.pace.or(d.pace);
                out.jerk = out.jerk.or(d.jerk);
                out.ease = out.ease.or(d.ease);
                out.matching = out.matching.or(d.matching);
                out.skate = out.skate.or(d.skate);
            }
        }
        out
    }

    /// Whether `sampling.posture` can pull toward the labels' postures
    /// (a frame model with postures.json).
    pub fn has_postures(&self) -> bool {
        matches!(self, MotionModel::Frame(s) if s.postures.is_some())
    }

    /// The label kinds the model's class heads classify.
    pub fn class_kinds(&self) -> Vec<String> {
        let classes = match self {
            MotionModel::Flat(s) => &s.config().classes,
            MotionModel::Frame(s) => &s.config().classes,
        };
        classes.iter().map(|(k, _)| k.clone()).collect()
    }

    /// The `max_jump` for a request that names none: the smallest the
    /// manifest lists for the label kinds asked for (`max_jump_by_kind`,
    /// frame model), else the recommended sampling's.
    pub fn default_max_jump<'a>(&self, kinds: impl IntoIterator<Item = &'a String>) -> u32 {
        let recommended = super::sampling::RECOMMENDED.max_jump;
        match self {
            MotionModel::Flat(_) => recommended,
            MotionModel::Frame(s) => kinds
                .into_iter()
                .filter_map(|k| s.manifest.max_jump_by_kind.get(k).copied())
                .min()
                .unwrap_or(recommended),
        }
    }

    /// A generation from these labels, continuing `seed_tokens` (whole
    /// frames).
    pub fn generator(
        &self,
        labels: &Labels,
        seed_tokens: &[u32],
        sampling: Sampling,
    ) -> Result<MotionGenerator, LmError> {
        Ok(match self {
            MotionModel::Flat(s) => {
                MotionGenerator::Flat(Generator::new(s.clone(), labels, seed_tokens, sampling)?)
            }
            MotionModel::Frame(s) => MotionGenerator::Frame(FrameGenerator::new(
                s.clone(),
                labels,
                seed_tokens,
                sampling,
            )?),
        })
    }

    /// A generation steered by the class heads ([`super::steer`]): every
    /// `every` frames the best of `candidates` continuations is kept.
    /// Frame model only.
    pub fn steered(
        &self,
        labels: &Labels,
        seed_tokens: &[u32],
        sampling: Sampling,
        (candidates, every): (u32, usize),
    ) -> Result<super::steer::Steered, LmError> {
        match self {
            MotionModel::Flat(_) => Err(LmError::invalid(
                "request",
                "rank_every",
                "steering needs the frame model (this server runs the flat GPT); rank_every 0 ranks whole clips",
            )),
            MotionModel::Frame(s) => {
                let seed = sampling.seed;
                let g = FrameGenerator::new(s.clone(), labels, seed_tokens, sampling)?;
                super::steer::Steered::new(g, labels, candidates, every, seed)
            }
        }
    }

    /// Class probabilities of a motion's frame tokens (whole frames of the
    /// vocabulary's `frame_len`), averaged over at most `max_windows`
    /// windows of the model's context.
    pub fn classify(
        &self,
        frame_tokens: &[u32],
        max_windows: usize,
    ) -> Result<ClassTable, LmError> {
        match self {
            MotionModel::Flat(s) => flat_classify(s, frame_tokens, max_windows),
            MotionModel::Frame(s) => {
                let c = s.config();
                if c.classes.is_empty() {
                    return Err(LmError::invalid(
                        "model",
                        "classes",
                        "this model has no class heads",
                    ));
                }
                let fl = c.slots + 1;
                let values: Vec<u32> = frame_tokens
                    .chunks_exact(fl)
                    .flat_map(|f| f[..c.slots].iter().copied())
                    .collect();
                let frames = values.len() / c.slots;
                if frames == 0 {
                    return Err(LmError::invalid(
                        "request",
                        "motion",
                        "no whole frame to classify",
                    ));
                }
                let w = c.max_frames.min(frames);
                let starts = classify_starts(frames, w, max_windows);
                let mut acc: Vec<Vec<f64>> =
                    c.classes.iter().map(|(_, v)| vec![0.0; v.len()]).collect();
                for &s0 in &starts {
                    let logits = s.classify(&values[s0 * c.slots..(s0 + w) * c.slots])?;
                    for (a, l) in acc.iter_mut().zip(logits) {
                        add_softmax(a, &l, 1.0 / starts.len() as f64);
                    }
                }
                Ok(class_table(&c.classes, acc))
            }
        }
    }
}

/// A running generation of either kind; both give one frame per call.
pub enum MotionGenerator {
    Flat(Generator),
    Frame(FrameGenerator),
}

impl MotionGenerator {
    /// The next frame's tokens (separator last); `forced[s]` fixes slot
    /// `s` (a joint prompt).
    pub fn next_frame(&mut self, forced: &[Option<u32>]) -> Result<Vec<u32>, LmError> {
        match self {
            MotionGenerator::Flat(g) => g.next_frame(forced),
            MotionGenerator::Frame(g) => g.next_frame(forced),
        }
    }

    /// Frames produced so far.
    pub fn produced(&self) -> usize {
        match self {
            MotionGenerator::Flat(g) => g.produced,
            MotionGenerator::Frame(g) => g.produced,
        }
    }
}
