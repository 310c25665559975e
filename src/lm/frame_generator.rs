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
        let mut g = FrameGenerator {
            session,
            tracks,
            lstate,
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
            window: self.window.clone(),
            before: self.before.clone(),
            h: self.h.clone(),
            rng: StdRng::seed_from_u64(seed),
            pace: self.pace.clone(),
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
        let pull = pull.as_deref().map(|p| p.for_frame(p1.as_deref()));
        // `sampling.draws` candidates; the one most typical of the model
        // is kept (greedy drawing makes the same frame every time).
        let n = if self.sampling.temperature == 0.0 {
            1
        } else {
            self.sampling.draws.max(1)
        };
        let mut cands = Vec::with_capacity(n as usize);
        for _ in 0..n {
            cands.push(self.draw_frame(
                &session,
                forced,
                (&vel, &prev, p1.as_deref()),
                pull.as_ref(),
                n > 1,
            )?);
        }
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
        let (mut frame, kept) = super::typical::most_typical(cands, |i| {
            jerks.as_ref().map_or(0.0, |j| j[i])
                + self
                    .pace
                    .as_ref()
                    .zip(paces.as_ref())
                    .map_or(0.0, |(h, ps)| h.cost(ps[i]))
        });
        if let (Some(h), Some(ps)) = (self.pace.as_mut(), &paces) {
            h.push(ps[kept]);
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
    /// One candidate frame drawn slot by slot through the local decoder,
    /// with its surprise under the model's own distribution (nats, the
    /// change head's; an escape also pays the absolute head's share among
    /// the bins outside the change window) and that surprise's expectation
    /// (the summed entropies of the slots' distributions, given the slots
    /// drawn before them). Forced slots count in neither, and nothing
    /// does unless `score` (a lone candidate needs no score: plain
    /// drawing pays nothing for it).
    fn draw_frame(
        &mut self,
        session: &FrameSession,
        forced: &[Option<u32>],
        (vel, prev, p1): (&[u32], &[u32], Option<&[u32]>),
        pull: Option<&super::posture::FramePull<'_>>,
        score: bool,
    ) -> Result<(Vec<u32>, f64, f64), LmError> {
        let c = session.config();
        let mut local = session.new_local_cache();
        let mut frame = Vec::with_capacity(c.slots + 1);
        let mut inp = c.start();
        let (mut surprise, mut expected) = (0.0, 0.0);
        for s in 0..c.slots {
            session.local_step(&mut self.lstate, &mut local, &self.h, inp, vel[s], prev[s])?;
            let out = &self.lstate.out;
            let tok = match forced[s] {
                Some(t) if (t as usize) < c.bins => t,
                Some(t) => {
                    return Err(LmError::invalid(
                        "request",
                        format!("prompt slot {s}"),
                        format!("token {t} is not a value token"),
                    ))
                }
                None => {
                    let t = draw(
                        &self.sampling,
                        &mut self.rng,
                        c,
                        (out.data(0), out.data(1)),
                        pull.map(|p| p.slot(s, &frame)).as_deref(),
                        p1.map(|p| p[s]),
                        c.wraps(s),
                    );
                    if score {
                        let (nll, h) = super::typical::surprise_of(
                            c,
                            (out.data(0), out.data(1)),
                            p1.map(|p| p[s]),
                            t,
                        );
                        surprise += nll;
                        expected += h;
                    }
                    t
                }
            };
            inp = c.change(p1.map(|p| p[s]), tok);
            frame.push(tok);
        }
        Ok((frame, surprise, expected))
    }
}

/// A slot's token: a change from the previous frame's token (or an
/// escape to the absolute head, with the change window masked out); the
/// absolute head alone when there is no previous frame. `wraps`: the
/// slot is an angle, whose bins meet round the back (max_jump measures
/// the shorter way round); else (the root's velocity and height) a jump
/// is the plain distance: before session 21 the height could wrap from
/// the floor to two metres up in one frame.
fn draw(
    sampling: &Sampling,
    rng: &mut StdRng,
    c: &FrameConfig,
    (rel, abs): (&[f32], &[f32]),
    pull: Option<&[f32]>,
    p1: Option<u32>,
    wraps: bool,
) -> u32 {
    // The posture pull: each bin's offset, added to the absolute head (only
    // built when drawn from: the first frame, or an escape) and to the
    // change that reaches the bin.
    let abs_pulled = || -> Vec<f32> {
        match pull {
            Some(u) => abs.iter().zip(u).map(|(a, b)| a + b).collect(),
            None => abs.to_vec(),
        }
    };
    let Some(p) = p1 else {
        return sampling.draw(&abs_pulled(), rng) as u32;
    };
    let bins = c.bins as i64;
    let r0 = c.radius as i64;
    // max_jump: a bin the slot may reach (an angle's the shorter way round). The
    // change window's targets lie within r0 bins, so they need masking
    // only under a limit below r0; the escape only when no bin outside the
    // window is reachable.
    let jump = sampling.max_jump as i64;
    let reach = |b: i64| {
        let d = (b - p as i64).abs();
        jump == 0 || if wraps { d.min(bins - d) } else { d } <= jump
    };
    let outside = |b: i64| (b - p as i64).abs() > r0 && reach(b);
    let moved;
    let rel = match pull {
        Some(u) => {
            let mut r = rel.to_vec();
            for (i, x) in r[..=2 * r0 as usize].iter_mut().enumerate() {
                *x += u[(p as i64 + i as i64 - r0).clamp(0, bins - 1) as usize];
            }
            // The escape is pulled too: by its bins' offsets averaged under
            // the absolute head's distribution over them (the bins it draws
            // from), so the product of the model and the pull is one
            // distribution over bins. Left unpulled, a slot away from its
            // posture, whose every change the pull lowers, escaped more
            // often and jumped (docs/RESULTS.md, "Session 40").
            r[c.esc() as usize] += escape_pull(abs, u, outside);
            moved = r;
            &moved[..]
        }
        None => rel,
    };
    let near = sampling.keep_near as i64;
    let can_escape = escapable(p as i64, r0, jump, bins, wraps);
    let mut limited;
    let rel = if jump > 0 && (jump < r0 || !can_escape) {
        limited = rel.to_vec();
        for (i, x) in limited[..=2 * r0 as usize].iter_mut().enumerate() {
            if !reach(p as i64 + i as i64 - r0) {
                *x = f32::NEG_INFINITY;
            }
        }
        if !can_escape {
            limited[c.esc() as usize] = f32::NEG_INFINITY;
        }
        &limited[..]
    } else {
        rel
    };
    // The small changes stay drawable however the tail is cut (keep_near).
    let k = sampling.draw_keeping(rel, rng, |i| {
        near > 0 && i != c.esc() as usize && (i as i64 - r0).abs() <= near
    }) as u32;
    if let Some(b) = c.apply_change(p, k) {
        return b;
    }
    let mut masked = abs_pulled();
    for (b, x) in masked.iter_mut().enumerate() {
        if !outside(b as i64) {
            *x = f32::NEG_INFINITY;
        }
    }
    sampling.draw(&masked, rng) as u32
}

/// The pull's offset to the escape class: ln Σ q(b) e^{u(b)} over the bins
/// an escape may land on (`outside`), q the absolute head's distribution
/// over them (0 when there are none).
fn escape_pull(abs: &[f32], u: &[f32], outside: impl Fn(i64) -> bool) -> f32 {
    let m = abs
        .iter()
        .enumerate()
        .filter(|&(b, _)| outside(b as i64))
        .fold(f32::NEG_INFINITY, |a, (_, &x)| a.max(x));
    if m == f32::NEG_INFINITY {
        return 0.0;
    }
    let (mut z, mut zu) = (0.0f64, 0.0f64);
    for (b, (&x, &o)) in abs.iter().zip(u).enumerate() {
        if outside(b as i64) {
            let q = ((x - m) as f64).exp();
            z += q;
            zu += q * (o as f64).exp();
        }
    }
    if zu > 0.0 {
        (zu / z).ln() as f32
    } else {
        f32::NEG_INFINITY
    }
}

/// Whether a slot at bin `p` can escape its change window (a bin more than
/// `r0` away) and still move at most `jump` bins (`jump` > 0), the
/// shorter way round where the slot `wraps`: a bin just outside the
/// window when `jump` > `r0`, else only a wrap-around one, at least
/// `bins − jump` away.
fn escapable(p: i64, r0: i64, jump: i64, bins: i64, wraps: bool) -> bool {
    let far = p.max(bins - 1 - p);
    far > r0 && (jump > r0 || (wraps && far >= bins - jump))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn max_jump_wraps_round_for_angles_only() {
        // Every escape's mass on bin 358, the slot at bin 2: 4 bins away
        // the short way round for an angle, 356 for the root's height.
        let c = crate::lm::frame::test_config();
        let mut rel = vec![f32::NEG_INFINITY; c.rel_classes()];
        rel[c.esc() as usize] = 0.0;
        let mut abs = vec![-10.0f32; c.bins];
        abs[358] = 10.0;
        let sampling = Sampling {
            temperature: 1.0,
            max_jump: 48,
            ..Sampling::default()
        };
        let mut rng = StdRng::seed_from_u64(1);
        let (angle, height) = (0, c.slots - 1);
        assert!(c.wraps(angle) && !c.wraps(height) && !c.wraps(c.slots - 3));
        let mut from_bin_2 = |slot: usize| {
            draw(
                &sampling,
                &mut rng,
                &c,
                (&rel, &abs),
                None,
                Some(2),
                c.wraps(slot),
            )
        };
        for _ in 0..50 {
            let a = from_bin_2(angle);
            assert_eq!(a, 358, "an angle may wrap round");
            let h = from_bin_2(height);
            assert!(h <= 2 + 48, "the height jumped from bin 2 to {h}");
        }
    }

    #[test]
    fn the_pull_weighs_the_escape_by_the_bins_it_lands_on() {
        // The model: every change and the escape alike (18 classes), the
        // absolute head flat. The pull leaves two bins, one step up from
        // the slot (bin 101) and one far (bin 300), and all but rules out
        // the rest. The product of the two puts 1/18 on bin 101 and
        // 1/18 · 1/343 on bin 300: an escape about one draw in 344. Left
        // unpulled, the escape would take half the draws.
        let c = crate::lm::frame::test_config();
        let rel = vec![0.0f32; c.rel_classes()];
        let abs = vec![0.0f32; c.bins];
        let mut u = vec![-50.0f32; c.bins];
        u[101] = 0.0;
        u[300] = 0.0;
        let sampling = Sampling {
            temperature: 1.0,
            ..Sampling::default()
        };
        let mut rng = StdRng::seed_from_u64(3);
        let n = 4000;
        let mut far = 0;
        for _ in 0..n {
            match draw(
                &sampling,
                &mut rng,
                &c,
                (&rel, &abs),
                Some(&u),
                Some(100),
                true,
            ) {
                101 => {}
                300 => far += 1,
                b => panic!("drew bin {b}, which the pull all but rules out"),
            }
        }
        assert!(far > 0 && far < n / 100, "{far} of {n} escaped");
        // The escape's offset itself: the mean of e^u under the head over
        // the bins it may land on.
        let outside = |b: i64| (b - 100).abs() > c.radius as i64;
        let half = vec![0.5f32.ln(); c.bins];
        assert!((escape_pull(&abs, &half, outside) - 0.5f32.ln()).abs() < 1e-6);
        let one = escape_pull(&abs, &u, outside);
        let want = (1.0f64 / (c.bins - 2 * c.radius - 1) as f64).ln() as f32;
        assert!((one - want).abs() < 1e-4, "{one} against {want}");
        assert_eq!(escape_pull(&abs, &u, |_| false), 0.0);
    }

    #[test]
    fn escapable_matches_a_search_over_every_bin() {
        for bins in [10i64, 17, 360] {
            for r0 in [1i64, 3, 4] {
                for jump in 1..=bins / 2 {
                    for p in 0..bins {
                        for wraps in [true, false] {
                            let search = (0..bins).any(|b| {
                                let d = (b - p).abs();
                                d > r0 && if wraps { d.min(bins - d) } else { d } <= jump
                            });
                            assert_eq!(
                                super::escapable(p, r0, jump, bins, wraps),
                                search,
                                "bins {bins} r0 {r0} jump {jump} p {p} wraps {wraps}"
                            );
                        }
                    }
                }
            }
        }
    }
}

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
