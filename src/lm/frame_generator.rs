//! The frame model's generator: one global step and one local step per
//! slot a frame, the global window sliding by halves (the next window's
//! cache filled as its frames come, so a slide costs no burst), optional
//! classifier-free guidance (two global tracks) and label steering
//! through the class heads' pose path ([`super::frame_steer`]).

use super::engine::Cache;
use super::frame::{local_context, FrameConfig};
use super::frame_runtime::{FrameSession, Step};
use super::sampling::Sampling;
use super::LmError;
use crate::motion::Labels;
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::sync::Arc;

/// One conditioning's side of the global transformer: its run state, its
/// conditioning row, the window's cache, the next window's cache (the
/// conditioning and the frames that will be kept at the next slide, filled
/// one frame at a time while the current window decodes, so a slide costs
/// no burst of work) and the latest global state.
struct Track {
    st: Step,
    cond: Vec<f32>,
    cache: Cache,
    next: Option<Cache>,
    h: Vec<f32>,
}

/// A running generation with the frame model: the global track (two under
/// guidance: the request's labels and none), the frames in the global
/// window, the last two frames and the random state.
pub struct FrameGenerator {
    session: Arc<FrameSession>,
    tracks: Vec<Track>,
    lstate: Step,
    /// The local decoder's run state for `sampling.draws` candidates side
    /// by side (one run a slot for all of them); None with one candidate
    /// or a local graph exported without a batch dimension.
    lbatch: Option<Step>,
    /// Frames in the global cache (after the conditioning row).
    window: Vec<Vec<u32>>,
    /// The frame before the window's first one, if any (its change codes).
    before: Option<Vec<u32>>,
    /// The state the next frame is decoded from (guided when two tracks).
    h: Vec<f32>,
    rng: StdRng,
    sampling: Sampling,
    /// The labels' posture pull (`sampling.posture`), if any.
    pull: Option<Arc<super::posture::Pull>>,
    /// The seed's pace held (`sampling.pace`), if any.
    pace: Option<super::pace::Pace>,
    /// The running pace the posture pull eases by (`sampling.ease`): a
    /// pull, a seed to measure against and a positive ease; else None.
    ease: Option<super::pace::Pace>,
    /// The asked-for labels' real frames the joints follow
    /// (`sampling.matching`), if any.
    library: Option<Arc<super::matching::Library>>,
    /// The planted-feet tracker the skate price reads (`sampling.skate`),
    /// if any.
    feet: Option<super::skate::Feet>,
    pub produced: usize,
    /// Per class kind (the config's order), the class heads' logits summed
    /// over the frames produced so far: read from the unlabelled track
    /// under guidance (as the heads were fitted), else the labelled one.
    cls_sum: Vec<Vec<f64>>,
}

impl FrameGenerator {
    /// Starts from the labels (errors name unknown kinds and values),
    /// continuing `seed_tokens` (whole frames of the vocabulary's
    /// `frame_len` tokens; the last half-window is kept).
    pub fn new(
        session: Arc<FrameSession>,
        labels: &Labels,
        seed_tokens: &[u32],
        sampling: Sampling,
    ) -> Result<FrameGenerator, LmError> {
        sampling.validate()?;
        let cond = session.cond(labels)?;
        let c = session.config().clone();
        let fl = c.slots + 1;
        if seed_tokens.len() % fl != 0 {
            return Err(LmError::invalid("request", "seed", "not whole frames"));
        }
        let frames: Vec<Vec<u32>> = seed_tokens
            .chunks_exact(fl)
            .map(|f| f[..c.slots].to_vec())
            .collect();
        if let Some(bad) = frames.iter().flatten().find(|&&t| t as usize >= c.bins) {
            return Err(LmError::invalid(
                "request",
                "seed",
                format!("token {bad} is not a value token"),
            ));
        }
        if sampling.context as usize > c.max_frames {
            return Err(LmError::invalid(
                "request",
                "sampling.context",
                format!(
                    "{} frames (this model's window holds at most {}; 0 = all of it)",
                    sampling.context, c.max_frames
                ),
            ));
        }
        let keep = (window_len(&c, &sampling) / 2).max(1).min(frames.len());
        let pull = if sampling.posture > 0.0 && !labels.is_empty() {
            let p = session.postures.as_ref().ok_or_else(|| {
                LmError::invalid(
                    "request",
                    "sampling.posture",
                    "this model has no label postures (postures.json; choreo postures writes one)",
                )
            })?;
            p.pull(labels, sampling.posture).map(Arc::new)
        } else {
            None
        };
        // Guidance needs labels to steer by and a model trained with the
        // conditioning dropped; otherwise it is plain conditioning.
        let guided = sampling.guidance != 1.0 && !labels.is_empty() && c.cond_every;
        let mut conds = vec![cond];
        if guided {
            conds.push(session.cond(&Labels::new())?);
        }
        let (_, lstate) = session.states()?;
        let tracks = conds
            .into_iter()
            .map(|cond| -> Result<Track, LmError> {
                Ok(Track {
                    st: session.states()?.0,
                    cond,
                    cache: session.new_global_cache(),
                    next: None,
                    h: Vec::new(),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let pace = if sampling.draws > 1 && sampling.temperature > 0.0 {
            super::pace::Pace::from_seed(sampling.pace, &session.manifest.vocabulary, &c, &frames)
        } else {
            None
        };
        // The ease reads only the tracker's running pace (`turn_ratio`),
        // never its cost, so the weight is a placeholder.
        let ease = if sampling.ease > 0.0 && pull.is_some() {
            super::pace::Pace::from_seed(1.0, &session.manifest.vocabulary, &c, &frames)
        } else {
            None
        };
        let library = if sampling.matching > 0.0 {
            Some(Arc::new(super::matching::Library::for_session(
                &session,
                labels,
                sampling.travel,
            )?))
        } else {
            None
        };
        let feet = if sampling.skate > 0.0 && sampling.draws > 1 {
            super::skate::Feet::new(&session.manifest.vocabulary, &frames)
        } else {
            None
        };
        let lbatch = batch_state(&session, &sampling)?;
        let mut g = FrameGenerator {
            library,
            feet,
            ease,
            session,
            tracks,
            lstate,
            lbatch,
            window: frames[frames.len() - keep..].to_vec(),
            before: (frames.len() > keep).then(|| frames[frames.len() - keep - 1].clone()),
            h: Vec::new(),
            rng: StdRng::seed_from_u64(sampling.seed),
            sampling,
            pull,
            pace,
            produced: 0,
            cls_sum: c.classes.iter().map(|(_, v)| vec![0.0; v.len()]).collect(),
        };
        g.encode_window()?;
        Ok(g)
    }

    /// An independent copy of this generation from here on, drawing with
    /// `seed`: the same window, caches and history (the caches are shared
    /// until either side writes), its own run states.
    pub fn fork(&self, seed: u64) -> Result<FrameGenerator, LmError> {
        let tracks = self
            .tracks
            .iter()
            .map(|t| -> Result<Track, LmError> {
                Ok(Track {
                    st: self.session.states()?.0,
                    cond: t.cond.clone(),
                    cache: t.cache.clone(),
                    next: t.next.clone(),
                    h: t.h.clone(),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(FrameGenerator {
            session: self.session.clone(),
            tracks,
            lstate: self.session.states()?.1,
            lbatch: batch_state(&self.session, &self.sampling)?,
            window: self.window.clone(),
            before: self.before.clone(),
            h: self.h.clone(),
            rng: StdRng::seed_from_u64(seed),
            pace: self.pace.clone(),
            ease: self.ease.clone(),
            library: self.library.clone(),
            feet: self.feet.clone(),
            sampling: Sampling {
                seed,
                ..self.sampling.clone()
            },
            pull: self.pull.clone(),
            produced: self.produced,
            cls_sum: self.cls_sum.clone(),
        })
    }

    pub fn config(&self) -> &FrameConfig {
        self.session.config()
    }

    /// Per class kind, the class heads' logits summed over the frames
    /// produced so far (their mean is what `classify` would softmax).
    pub fn class_logit_sums(&self) -> &[Vec<f64>] {
        &self.cls_sum
    }

    /// The state the local decoder reads: the conditioned track's, or under
    /// guidance `h_u + w (h_c − h_u)`.
    fn mix(&mut self) {
        let w = self.sampling.guidance as f32;
        match self.tracks.as_slice() {
            [c, u] => {
                self.h.clear();
                self.h
                    .extend(c.h.iter().zip(&u.h).map(|(hc, hu)| hu + w * (hc - hu)));
            }
            [c] => self.h.clone_from(&c.h),
            _ => {}
        }
    }

    /// Re-encodes the conditioning and the window's frames from an empty
    /// cache, on every track.
    fn encode_window(&mut self) -> Result<(), LmError> {
        let s = self.session.clone();
        for t in &mut self.tracks {
            t.next = None;
            t.cache = s.new_global_cache();
            t.h = s.global_step(&mut t.st, &mut t.cache, &t.cond, None)?.0;
            for i in 0..self.window.len() {
                let p1 = if i == 0 {
                    self.before.as_deref()
                } else {
                    Some(self.window[i - 1].as_slice())
                };
                t.h = s
                    .global_step(
                        &mut t.st,
                        &mut t.cache,
                        &t.cond,
                        Some((&self.window[i], p1)),
                    )?
                    .0;
            }
        }
        self.mix();
        Ok(())
    }

    fn last(&self, k: usize) -> Option<&[u32]> {
        let n = self.window.len();
        if k <= n {
            Some(self.window[n - k].as_slice())
        } else if k == n + 1 {
            self.before.as_deref()
        } else {
            None
        }
    }

    /// The next frame's tokens (the vocabulary's `frame_len`, separator
    /// last). `forced[s]` fixes slot `s` (a joint prompt).
    pub fn next_frame(&mut self, forced: &[Option<u32>]) -> Result<Vec<u32>, LmError> {
        let session = self.session.clone();
        let c = session.config();
        let fl = c.slots + 1;
        if forced.len() != fl {
            return Err(LmError::invalid(
                "request",
                "prompt",
                format!("{} slots, want {fl}", forced.len()),
            ));
        }
        let p1 = self.last(1).map(|f| f.to_vec());
        let p2 = self.last(2).map(|f| f.to_vec());
        let (vel, prev) = local_context(c, p1.as_deref(), p2.as_deref());
        let pull = self.pull.clone();
        // The pull eases off while the clip is slower than its seed.
        let scale = self
            .ease
            .as_ref()
            .map_or(1.0, |e| e.turn_ratio().min(1.0).powf(self.sampling.ease));
        let pull = pull
            .as_deref()
            .map(|p| p.for_frame(p1.as_deref(), scale as f32));
        // `sampling.draws` candidates; the one most typical of the model
        // is kept (greedy drawing makes the same frame every time).
        let n = if self.sampling.temperature == 0.0 {
            1
        } else {
            self.sampling.draws.max(1)
        };
        // Motion matching's target for this frame (it needs a frame before),
        // as each slot's offsets: worked out once a frame, shared by every
        // candidate.
        let matched: Option<Vec<Option<Vec<f32>>>> =
            self.library.as_deref().zip(p1.as_deref()).map(|(l, p)| {
                let t = l.target(p, p2.as_deref());
                (0..c.slots)
                    .map(|s| l.offsets(&t, s, self.sampling.matching))
                    .collect()
            });
        let follow = matched.as_deref();
        let ctx = (&vel[..], &prev[..], p1.as_deref());
        let cands = if n > 1 && self.lbatch.is_some() {
            self.draw_frames(
                &session,
                forced,
                ctx,
                (pull.as_ref(), follow),
                (n as usize, true),
            )?
        } else {
            let mut cands = Vec::with_capacity(n as usize);
            for _ in 0..n {
                // A graph without the batch dimension: one at a time.
                let one = (1, n > 1);
                cands.extend(self.draw_frames(
                    &session,
                    forced,
                    ctx,
                    (pull.as_ref(), follow),
                    one,
                )?);
            }
            cands
        };
        // The pace hold (it has a seed, so a previous frame) prices each
        // candidate, and records the kept one's pace.
        let vocab = &session.manifest.vocabulary;
        let paces: Option<Vec<_>> = self.pace.as_ref().and(p1.as_deref()).map(|p| {
            cands
                .iter()
                .map(|(f, _, _)| super::pace::frame_pace(vocab, &c, p2.as_deref(), p, f))
                .collect()
        });
        // The jerk price (it needs three frames before).
        let p3 = self.last(3).map(|f| f.to_vec());
        let jerks: Option<Vec<f64>> = match (p3.as_deref(), p2.as_deref(), p1.as_deref()) {
            (Some(a), Some(b), Some(d)) if self.sampling.jerk > 0.0 && cands.len() > 1 => Some(
                cands
                    .iter()
                    .map(|(f, _, _)| {
                        self.sampling.jerk * super::typical::frame_jerk(&c, [a, b, d], f)
                    })
                    .collect(),
            ),
            _ => None,
        };
        // The skate price (it needs the frame before).
        let skates: Option<Vec<f64>> = match (self.feet.as_mut(), p1.as_deref()) {
            (Some(feet), Some(p)) if cands.len() > 1 => {
                let fs: Vec<&[u32]> = cands.iter().map(|(f, _, _)| f.as_slice()).collect();
                let k = self.sampling.skate;
                Some(
                    feet.costs(vocab, p, &fs)
                        .into_iter()
                        .map(|x| k * x)
                        .collect(),
                )
            }
            _ => None,
        };
        let (mut frame, kept) = super::typical::most_typical(cands, |i| {
            jerks.as_ref().map_or(0.0, |j| j[i])
                + skates.as_ref().map_or(0.0, |s| s[i])
                + self
                    .pace
                    .as_ref()
                    .zip(paces.as_ref())
                    .map_or(0.0, |(h, ps)| h.cost(ps[i]))
        });
        if let (Some(h), Some(ps)) = (self.pace.as_mut(), &paces) {
            h.push(ps[kept]);
        }
        // The ease's tracker records it too (the hold measured it already,
        // where there is one).
        if let (Some(e), Some(p)) = (self.ease.as_mut(), p1.as_deref()) {
            e.push(match &paces {
                Some(ps) => ps[kept],
                None => super::pace::frame_pace(vocab, &c, p2.as_deref(), p, &frame),
            });
        }
        // The global window: when full, keep the last half, whose cache
        // (`next`) was filled as those frames came; then feed the frame.
        let m = window_len(&c, &self.sampling);
        let keep = (m / 2).max(1);
        if self.window.len() >= m {
            let cut = self.window.len() - keep;
            self.before = Some(self.window[cut - 1].clone());
            self.window.drain(..cut);
            let ready = self
                .tracks
                .iter()
                .all(|t| t.next.as_ref().is_some_and(|n| n.len() == 1 + keep));
            if ready {
                for t in &mut self.tracks {
                    t.cache = t.next.take().expect("checked");
                }
            } else {
                self.encode_window()?;
            }
        }
        let i = self.window.len();
        let read = self.tracks.len() - 1;
        for (ti, t) in self.tracks.iter_mut().enumerate() {
            let (h, cls) = session.global_step(
                &mut t.st,
                &mut t.cache,
                &t.cond,
                Some((&frame, p1.as_deref())),
            )?;
            t.h = h;
            if ti == read {
                for (sum, l) in self.cls_sum.iter_mut().zip(&cls) {
                    for (a, &x) in sum.iter_mut().zip(l) {
                        *a += x as f64;
                    }
                }
            }
            if i >= m - keep {
                if i == m - keep {
                    let mut n = session.new_global_cache();
                    session.global_step(&mut t.st, &mut n, &t.cond, None)?;
                    t.next = Some(n);
                }
                if let Some(n) = t.next.as_mut() {
                    session.global_step(&mut t.st, n, &t.cond, Some((&frame, p1.as_deref())))?;
                }
            }
        }
        self.mix();
        self.window.push(frame.clone());
        frame.push(session.manifest.vocabulary.sep());
        self.produced += 1;
        Ok(frame)
    }
}

impl FrameGenerator {
    /// `n` candidate frames drawn slot by slot through the local decoder,
    /// side by side (one local run a slot for all; `n` > 1 needs the
    /// batched state), each with its surprise under the model's own
    /// distribution (nats, the change head's; an escape also pays the
    /// absolute head's share among the bins outside the change window) and
    /// that surprise's expectation (the summed entropies of the slots'
    /// distributions, given the slots drawn before them). Forced slots
    /// count in neither, and nothing does unless `score` (a lone candidate
    /// needs no score: plain drawing pays nothing for it).
    fn draw_frames(
        &mut self,
        session: &FrameSession,
        forced: &[Option<u32>],
        (vel, prev, p1): (&[u32], &[u32], Option<&[u32]>),
        (pull, follow): (Option<&super::posture::FramePull<'_>>, Follow<'_>),
        (n, score): (usize, bool),
    ) -> Result<Vec<(Vec<u32>, f64, f64)>, LmError> {
        let c = session.config();
        let st = match self.lbatch.as_mut() {
            Some(st) if n > 1 => st,
            _ => &mut self.lstate,
        };
        let mut frames = vec![Vec::with_capacity(c.slots + 1); n];
        let mut scores = vec![(0.0, 0.0); n];
        let (sampling, rng) = (&self.sampling, &mut self.rng);
        session.decode_rows(
            st,
            &self.h,
            (vel, prev, p1),
            &mut frames,
            |b, s, logits, frame| {
                slot_token(
                    (sampling, &mut *rng, c),
                    (s, forced[s], p1),
                    logits,
                    (pull, follow),
                    frame,
                    score.then_some(&mut scores[b]),
                )
            },
        )?;
        // A joint that went round the half-turn edge in one slot only
        // gets the whole flip (docs/RESULTS.md, "Session 45").
        if let Some(p1) = p1 {
            for f in frames.iter_mut() {
                super::flips::finish(f, p1, forced, (c.slots, c.bins, sampling.max_jump));
            }
        }
        Ok(frames
            .into_iter()
            .zip(scores)
            .map(|(f, (a, b))| (f, a, b))
            .collect())
    }
}

/// The batched local run state for a generator drawing `sampling.draws`
/// candidates, where there are several and the graph can batch them.
fn batch_state(session: &FrameSession, sampling: &Sampling) -> Result<Option<Step>, LmError> {
    if sampling.draws > 1 && sampling.temperature > 0.0 {
        session.local_batch(sampling.draws as usize)
    } else {
        Ok(None)
    }
}

/// Slot `s`'s token in a candidate frame (`frame`: its slots so far): the
/// forced one (a joint prompt), else one drawn from the slot's change and
/// absolute logits; with `score`, its surprise and the slot's entropy are
/// added to it (forced slots count in neither).
fn slot_token(
    (sampling, rng, c): (&Sampling, &mut StdRng, &FrameConfig),
    (s, forced, p1): (usize, Option<u32>, Option<&[u32]>),
    logits: (&[f32], &[f32]),
    (pull, follow): (Option<&super::posture::FramePull<'_>>, Follow<'_>),
    frame: &[u32],
    score: Option<&mut (f64, f64)>,
) -> Result<u32, LmError> {
    match forced {
        Some(t) if (t as usize) < c.bins => Ok(t),
        Some(t) => Err(LmError::invalid(
            "request",
            format!("prompt slot {s}"),
            format!("token {t} is not a value token"),
        )),
        None => {
            // A followed slot (motion matching) is pulled toward its target
            // only; the postures keep the rest (the root's tilt).
            let offsets = match follow.and_then(|f| f[s].as_deref()) {
                Some(m) => Some(std::borrow::Cow::Borrowed(m)),
                None => pull.map(|p| p.slot(s, frame, Some((c.radius, sampling.max_jump)))),
            };
            let t = super::frame_draw::draw(
                sampling,
                rng,
                c,
                logits,
                offsets.as_deref(),
                p1.map(|p| p[s]),
                c.wraps(s),
            );
            if let Some((surprise, expected)) = score {
                let (nll, h) = super::typical::surprise_of(c, logits, p1.map(|p| p[s]), t);
                *surprise += nll;
                *expected += h;
            }
            Ok(t)
        }
    }
}

/// Motion matching for one frame: per slot, the logit offsets toward the
/// frame's target (None for a slot not followed).
type Follow<'a> = Option<&'a [Option<Vec<f32>>]>;

/// The frames the global window holds: `sampling.context` (never more
/// than the model's window: [`FrameGenerator::new`] refuses that), or the
/// model's whole window when 0. The window slides by halves, so the model
/// reads between half of it and all of it.
fn window_len(c: &super::frame::FrameConfig, s: &Sampling) -> usize {
    match s.context as usize {
        0 => c.max_frames,
        n => n,
    }
}
