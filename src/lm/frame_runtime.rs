//! The frame model on the model runtime (`engine`: tract or ort): two step graphs with static shapes (global and
//! local), fixed-capacity key/value caches written in place, and the
//! generator that decodes one frame per call (one global step plus one
//! local step per slot).

use super::engine::{Cache, Engine, Graph, GraphSpec, GraphState, In, Outputs};
use super::frame::{
    frame_changes, global_inputs, global_outputs, local_context, local_inputs, local_outputs,
    FrameConfig, FrameManifest,
};
use super::generate::Sampling;
use super::LmError;
use crate::motion::Labels;
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::path::Path;
use std::sync::Arc;

/// A loaded frame model: the manifest and both graphs, shared by requests.
pub struct FrameSession {
    pub manifest: FrameManifest,
    global: Arc<dyn Graph>,
    local: Arc<dyn Graph>,
}

/// A global or local run state with its output buffers.
struct Step {
    st: Box<dyn GraphState>,
    out: Outputs,
}

impl FrameSession {
    /// Loads a frame model folder, checking the manifest against both
    /// graphs (hashes, input and output names).
    pub fn load(path: &Path) -> Result<FrameSession, LmError> {
        FrameSession::load_with(path, &Engine::tract())
    }

    /// Loads it on `engine`'s runtime.
    pub fn load_with(path: &Path, engine: &Engine) -> Result<FrameSession, LmError> {
        let (manifest, g, l) = FrameManifest::load(path)?;
        let c = &manifest.config;
        let name = |f: &str| path.join(f).display().to_string();
        let global = engine.load(
            &g,
            &GraphSpec {
                inputs: &global_inputs(c),
                outputs: global_outputs(c).len(),
                file: &name(&manifest.global_onnx),
                f32_shapes: &[],
            },
        )?;
        let local = engine.load(
            &l,
            &GraphSpec {
                inputs: &local_inputs(c),
                outputs: local_outputs(c).len(),
                file: &name(&manifest.local_onnx),
                f32_shapes: &[],
            },
        )?;
        Ok(FrameSession {
            manifest,
            global,
            local,
        })
    }

    pub fn config(&self) -> &FrameConfig {
        &self.manifest.config
    }

    /// Fresh run states for the global and local plans (one pair per
    /// generator: their buffers are reused from step to step).
    fn states(&self) -> Result<(Step, Step), LmError> {
        let step = |g: &Arc<dyn Graph>| -> Result<Step, LmError> {
            Ok(Step {
                st: g.spawn()?,
                out: Outputs::default(),
            })
        };
        Ok((step(&self.global)?, step(&self.local)?))
    }

    fn new_global_cache(&self) -> Cache {
        let c = self.config();
        Cache::new(
            c.global_layers,
            c.global_heads,
            c.max_frames + 1,
            c.d_global / c.global_heads,
        )
    }

    fn new_local_cache(&self) -> Cache {
        let c = self.config();
        Cache::new(
            c.local_layers,
            c.local_heads,
            c.slots,
            c.d_local / c.local_heads,
        )
    }

    /// One global step: the conditioning (`frame` = None) or one frame of
    /// value tokens after `p1`. Returns the state and the class logits.
    fn global_step(
        &self,
        st: &mut Step,
        cache: &mut Cache,
        cond: &[f32],
        frame: Option<(&[u32], Option<&[u32]>)>,
    ) -> Result<(Vec<f32>, Vec<Vec<f32>>), LmError> {
        let c = self.config();
        let s = c.slots;
        let (val, chg, is_cond): (Vec<i64>, Vec<i64>, f32) = match frame {
            None => (vec![0; s], vec![c.none() as i64; s], 1.0),
            Some((f, p1)) => (
                f.iter().map(|&t| t as i64).collect(),
                frame_changes(c, f, p1).iter().map(|&t| t as i64).collect(),
                0.0,
            ),
        };
        let bias = cache.bias();
        let pos = [cache.len() as i64];
        let inputs = [
            In::I64(&[1, s], &val),
            In::I64(&[1, s], &chg),
            In::F32(&[1, c.vocab_size], cond),
            In::F32(&[1, 1], &[is_cond]),
            In::I64(&[1], &pos),
            In::F32(&[1, bias.len()], bias),
        ];
        st.st.run(&inputs, Some(cache), &mut st.out)?;
        let nk = c.classes.len();
        cache.push(&st.out, 1 + nk)?;
        let h = st.out.data(0).to_vec();
        let cls = (1..1 + nk).map(|i| st.out.data(i).to_vec()).collect();
        Ok((h, cls))
    }

    /// One local step at slot `cache.len()`: change and absolute logits,
    /// left in `st.out` (0: change, 1: absolute).
    fn local_step(
        &self,
        st: &mut Step,
        cache: &mut Cache,
        ctx: &[f32],
        inp: u32,
        vel: u32,
        prev: u32,
    ) -> Result<(), LmError> {
        let c = self.config();
        let bias = cache.bias();
        let ids = [inp as i64, vel as i64, prev as i64, cache.len() as i64];
        let inputs = [
            In::F32(&[1, c.d_global], ctx),
            In::I64(&[1], &ids[0..1]),
            In::I64(&[1], &ids[1..2]),
            In::I64(&[1], &ids[2..3]),
            In::I64(&[1], &ids[3..4]),
            In::F32(&[1, bias.len()], bias),
        ];
        st.st.run(&inputs, Some(cache), &mut st.out)?;
        cache.push(&st.out, 2)
    }

    /// Step timings for `choreo bench model`: `repeats` global steps with
    /// `past` frames cached and `repeats` local steps at slot `slots / 2`
    /// (random-free inputs; the caches are fixed-capacity, so the cost does
    /// not depend on how full they are). Returns the per-step times in ms,
    /// (global, local).
    pub fn time_steps(&self, past: usize, repeats: usize) -> Result<(Vec<f64>, Vec<f64>), LmError> {
        let c = self.config().clone();
        let cond = self.cond(&Labels::new())?;
        let (mut gs, mut ls) = self.states()?;
        let mut cache = self.new_global_cache();
        self.global_step(&mut gs, &mut cache, &cond, None)?;
        let frame = vec![(c.bins / 2) as u32; c.slots];
        let past = past.min(c.max_frames - 1);
        for _ in 0..past {
            self.global_step(&mut gs, &mut cache, &cond, Some((&frame, Some(&frame))))?;
        }
        let mut g = Vec::with_capacity(repeats);
        let mut h = Vec::new();
        for _ in 0..repeats {
            let t = std::time::Instant::now();
            h = self
                .global_step(&mut gs, &mut cache, &cond, Some((&frame, Some(&frame))))?
                .0;
            g.push(t.elapsed().as_secs_f64() * 1e3);
            cache.pop();
        }
        let mut l = Vec::with_capacity(repeats);
        let mut local = self.new_local_cache();
        let mid = c.slots / 2;
        for _ in 0..mid {
            self.local_step(&mut ls, &mut local, &h, c.radius as u32, c.radius as u32, 0)?;
        }
        for _ in 0..repeats {
            let t = std::time::Instant::now();
            self.local_step(&mut ls, &mut local, &h, c.radius as u32, c.radius as u32, 0)?;
            l.push(t.elapsed().as_secs_f64() * 1e3);
            local.pop();
        }
        Ok((g, l))
    }

    /// The conditioning row for `labels` (`<bos>` and one token per label).
    pub fn cond(&self, labels: &Labels) -> Result<Vec<f32>, LmError> {
        let c = self.config();
        let ids =
            super::generate::request_prefix(&self.manifest.vocabulary, &c.cond_kinds, labels)?;
        let mut row = vec![0f32; c.vocab_size];
        for id in ids {
            row[id as usize] = 1.0;
        }
        Ok(row)
    }

    /// Teacher-forced logits along `frames` (value tokens, from a
    /// sequence's start) under the conditioning row `cond`: per frame, the
    /// change logits (`slots × rel_classes`) and absolute logits
    /// (`slots × bins`), row-major. For parity checks and scoring.
    pub fn teacher_forced(
        &self,
        cond: &[f32],
        frames: &[Vec<u32>],
    ) -> Result<Vec<(Vec<f32>, Vec<f32>)>, LmError> {
        let c = self.config();
        if frames.len() > c.max_frames {
            return Err(LmError::invalid(
                "request",
                "frames",
                format!(
                    "{} frames, the context holds {}",
                    frames.len(),
                    c.max_frames
                ),
            ));
        }
        let (mut gs, mut ls) = self.states()?;
        let mut cache = self.new_global_cache();
        let (mut h, _) = self.global_step(&mut gs, &mut cache, cond, None)?;
        let mut out = Vec::with_capacity(frames.len());
        for (f, frame) in frames.iter().enumerate() {
            let p1 = (f > 0).then(|| frames[f - 1].as_slice());
            let p2 = (f > 1).then(|| frames[f - 2].as_slice());
            let (vel, prev) = local_context(c, p1, p2);
            let mut local = self.new_local_cache();
            let (mut rels, mut abss) = (Vec::new(), Vec::new());
            let mut inp = c.start();
            for s in 0..c.slots {
                self.local_step(&mut ls, &mut local, &h, inp, vel[s], prev[s])?;
                let (r, a) = (ls.out.data(0).to_vec(), ls.out.data(1).to_vec());
                rels.extend(r);
                abss.extend(a);
                inp = c.change(p1.map(|p| p[s]), frame[s]);
            }
            out.push((rels, abss));
            h = self
                .global_step(&mut gs, &mut cache, cond, Some((frame, p1)))?
                .0;
        }
        Ok(out)
    }

    /// Runs the global transformer, unconditioned, along whole frames of
    /// value tokens (`slots` each, at most the context) and hands each
    /// frame's state and class logits to `visit`. Returns the frame count.
    fn walk_frames(
        &self,
        values: &[u32],
        mut visit: impl FnMut(Vec<f32>, Vec<Vec<f32>>),
    ) -> Result<usize, LmError> {
        let c = self.config();
        let s = c.slots;
        let n = (values.len() / s).min(c.max_frames);
        if n == 0 {
            return Err(LmError::invalid("request", "motion", "no whole frame"));
        }
        let cond = self.cond(&Labels::new())?;
        let (mut gs, _) = self.states()?;
        let mut cache = self.new_global_cache();
        self.global_step(&mut gs, &mut cache, &cond, None)?;
        for f in 0..n {
            let frame = &values[f * s..(f + 1) * s];
            let p1 = (f > 0).then(|| &values[(f - 1) * s..f * s]);
            let (h, cls) = self.global_step(&mut gs, &mut cache, &cond, Some((frame, p1)))?;
            visit(h, cls);
        }
        Ok(n)
    }

    /// The global states along whole frames of value tokens, pooled: the
    /// mean state and the mean absolute change of the state from frame to
    /// frame, concatenated (`2 × d_global`). The search embedding `lm`.
    pub fn pooled_states(&self, values: &[u32]) -> Result<Vec<f32>, LmError> {
        let d = self.config().d_global;
        let mut sum = vec![0f32; 2 * d];
        let mut last: Option<Vec<f32>> = None;
        let n = self.walk_frames(values, |h, _| {
            for (o, x) in sum[..d].iter_mut().zip(&h) {
                *o += x;
            }
            if let Some(prev) = &last {
                for ((o, x), p) in sum[d..].iter_mut().zip(&h).zip(prev) {
                    *o += (x - p).abs();
                }
            }
            last = Some(h);
        })?;
        sum[..d].iter_mut().for_each(|x| *x /= n as f32);
        sum[d..]
            .iter_mut()
            .for_each(|x| *x /= (n - 1).max(1) as f32);
        Ok(sum)
    }

    /// Class logits per kind (manifest order) of whole frames of value
    /// tokens (`slots` each), unconditioned: the mean over frames of each
    /// step's class logits (= the head on the mean state).
    pub fn classify(&self, values: &[u32]) -> Result<Vec<Vec<f32>>, LmError> {
        let c = self.config();
        let mut sums: Vec<Vec<f32>> = c.classes.iter().map(|(_, v)| vec![0.0; v.len()]).collect();
        let n = self.walk_frames(values, |_, cls| {
            for (acc, x) in sums.iter_mut().zip(cls) {
                for (a, b) in acc.iter_mut().zip(x) {
                    *a += b;
                }
            }
        })?;
        for acc in sums.iter_mut() {
            acc.iter_mut().for_each(|a| *a /= n as f32);
        }
        Ok(sums)
    }
}

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
    pub produced: usize,
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
        let keep = (c.max_frames / 2).max(1).min(frames.len());
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
        let mut g = FrameGenerator {
            session,
            tracks,
            lstate,
            window: frames[frames.len() - keep..].to_vec(),
            before: (frames.len() > keep).then(|| frames[frames.len() - keep - 1].clone()),
            h: Vec::new(),
            rng: StdRng::seed_from_u64(sampling.seed),
            sampling,
            produced: 0,
        };
        g.encode_window()?;
        Ok(g)
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
        let mut local = session.new_local_cache();
        let mut frame = Vec::with_capacity(fl);
        let mut inp = c.start();
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
                None => draw(
                    &self.sampling,
                    &mut self.rng,
                    c,
                    out.data(0),
                    out.data(1),
                    p1.as_ref().map(|p| p[s]),
                ),
            };
            inp = c.change(p1.as_ref().map(|p| p[s]), tok);
            frame.push(tok);
        }
        // The global window: when full, keep the last half, whose cache
        // (`next`) was filled as those frames came; then feed the frame.
        let m = c.max_frames;
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
        for t in &mut self.tracks {
            t.h = session
                .global_step(
                    &mut t.st,
                    &mut t.cache,
                    &t.cond,
                    Some((&frame, p1.as_deref())),
                )?
                .0;
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

/// A slot's token: a change from the previous frame's token (or an
/// escape to the absolute head, with the change window masked out); the
/// absolute head alone when there is no previous frame.
fn draw(
    sampling: &Sampling,
    rng: &mut StdRng,
    c: &FrameConfig,
    rel: &[f32],
    abs: &[f32],
    p1: Option<u32>,
) -> u32 {
    let Some(p) = p1 else {
        return sampling.draw(abs, rng) as u32;
    };
    // The small changes stay drawable however the tail is cut (keep_near).
    let (r0, near) = (c.radius as i64, sampling.keep_near as i64);
    let k = sampling.draw_keeping(rel, rng, |i| {
        near > 0 && i != c.esc() as usize && (i as i64 - r0).abs() <= near
    }) as u32;
    if k != c.esc() {
        return (p as i64 + k as i64 - c.radius as i64).clamp(0, c.bins as i64 - 1) as u32;
    }
    let mut masked = abs.to_vec();
    let r = c.radius as i64;
    for (b, x) in masked.iter_mut().enumerate() {
        if (b as i64 - p as i64).abs() <= r {
            *x = f32::NEG_INFINITY;
        }
    }
    sampling.draw(&masked, rng) as u32
}
