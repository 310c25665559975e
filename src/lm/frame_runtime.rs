//! The frame model in tract: two step plans with static shapes (global and
//! local), fixed-capacity key/value caches written in place, and the
//! generator that decodes one frame per call (one global step plus one
//! local step per slot).

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
use tract_onnx::prelude::*;

type Plan = Arc<TypedRunnableModel>;

fn rt(e: impl std::fmt::Display) -> LmError {
    LmError::Runtime(e.to_string())
}

/// A plan output's floats, row-major.
fn floats(t: &Tensor) -> Result<&[f32], LmError> {
    t.try_as_plain_ram()
        .map_err(rt)?
        .as_slice::<f32>()
        .map_err(rt)
}

/// A loaded frame model: the manifest and both plans, shared by requests.
pub struct FrameSession {
    pub manifest: FrameManifest,
    global: Plan,
    local: Plan,
}

fn plan(bytes: &[u8], want_in: &[String], want_out: &[String]) -> TractResult<Plan> {
    let model = tract_onnx::onnx().model_for_read(&mut std::io::Cursor::new(bytes))?;
    let got_in: Vec<String> = model
        .input_outlets()?
        .iter()
        .map(|o| model.node(o.node).name.clone())
        .collect();
    let got_out: Vec<String> = model
        .output_outlets()?
        .iter()
        .map(|o| model.node(o.node).name.clone())
        .collect();
    if got_in != want_in || got_out.len() != want_out.len() {
        anyhow::bail!(
            "the graph's inputs {got_in:?} (and {} outputs) are not the {want_in:?} (and {} outputs) the manifest's config implies",
            got_out.len(),
            want_out.len()
        );
    }
    model.into_optimized()?.into_runnable()
}

/// Key/value caches of fixed capacity, `[1, heads, cap, d_head]` per layer,
/// and how many rows hold positions.
struct Cache {
    k: Vec<Arc<Tensor>>,
    v: Vec<Arc<Tensor>>,
    heads: usize,
    cap: usize,
    dh: usize,
    len: usize,
}

impl Cache {
    fn new(layers: usize, heads: usize, cap: usize, dh: usize) -> Cache {
        let z = || Arc::new(Tensor::zero::<f32>(&[1, heads, cap, dh]).expect("cache tensor"));
        Cache {
            k: (0..layers).map(|_| z()).collect(),
            v: (0..layers).map(|_| z()).collect(),
            heads,
            cap,
            dh,
            len: 0,
        }
    }

    /// 0 over the filled rows and the new position, −1e9 elsewhere.
    fn bias(&self) -> Tensor {
        let mut b = vec![-1e9f32; self.cap + 1];
        for x in b.iter_mut().take(self.len) {
            *x = 0.0;
        }
        b[self.cap] = 0.0;
        Tensor::from_shape(&[1, self.cap + 1], &b).expect("bias")
    }

    fn inputs(&self, into: &mut TVec<TValue>) {
        for (k, v) in self.k.iter().zip(&self.v) {
            into.push(TValue::from_const(k.clone()));
            into.push(TValue::from_const(v.clone()));
        }
    }

    /// Writes the new position's keys and values (`[1, heads, 1, dh]`
    /// each, alternating k, v per layer) at row `len`.
    fn push(&mut self, new: &[TValue]) -> Result<(), LmError> {
        let (p, dh, cap) = (self.len, self.dh, self.cap);
        for (l, pair) in new.chunks_exact(2).enumerate() {
            for (dst, src) in [(&mut self.k[l], &pair[0]), (&mut self.v[l], &pair[1])] {
                let src = floats(src)?;
                let t = Arc::make_mut(dst);
                let mut view = t.to_plain_array_view_mut::<f32>().map_err(rt)?;
                let d = view
                    .as_slice_mut()
                    .ok_or_else(|| rt("cache tensor is not contiguous"))?;
                for h in 0..self.heads {
                    d[(h * cap + p) * dh..(h * cap + p + 1) * dh]
                        .copy_from_slice(&src[h * dh..(h + 1) * dh]);
                }
            }
        }
        self.len += 1;
        Ok(())
    }
}

impl FrameSession {
    /// Loads a frame model folder, checking the manifest against both
    /// graphs (hashes, input and output names).
    pub fn load(path: &Path) -> Result<FrameSession, LmError> {
        let (manifest, g, l) = FrameManifest::load(path)?;
        let c = &manifest.config;
        let name = |f: &str| path.join(f).display().to_string();
        let global = plan(&g, &global_inputs(c), &global_outputs(c))
            .map_err(|e| LmError::invalid(name(&manifest.global_onnx), "graph", e.to_string()))?;
        let local = plan(&l, &local_inputs(c), &local_outputs(c))
            .map_err(|e| LmError::invalid(name(&manifest.local_onnx), "graph", e.to_string()))?;
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
    fn states(&self) -> Result<(TypedSimpleState, TypedSimpleState), LmError> {
        Ok((
            self.global.spawn().map_err(rt)?,
            self.local.spawn().map_err(rt)?,
        ))
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
        st: &mut TypedSimpleState,
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
        let mut inputs: TVec<TValue> = TVec::new();
        inputs.push(Tensor::from_shape(&[1, s], &val).map_err(rt)?.into_tvalue());
        inputs.push(Tensor::from_shape(&[1, s], &chg).map_err(rt)?.into_tvalue());
        inputs.push(
            Tensor::from_shape(&[1, c.vocab_size], cond)
                .map_err(rt)?
                .into_tvalue(),
        );
        inputs.push(
            Tensor::from_shape(&[1, 1], &[is_cond])
                .map_err(rt)?
                .into_tvalue(),
        );
        inputs.push(
            Tensor::from_shape(&[1], &[cache.len as i64])
                .map_err(rt)?
                .into_tvalue(),
        );
        inputs.push(cache.bias().into_tvalue());
        cache.inputs(&mut inputs);
        let out = st.run(inputs).map_err(rt)?;
        let nk = c.classes.len();
        cache.push(&out[1 + nk..])?;
        let flat = |t: &TValue| -> Result<Vec<f32>, LmError> { Ok(floats(t)?.to_vec()) };
        let h = flat(&out[0])?;
        let cls = out[1..1 + nk].iter().map(flat).collect::<Result<_, _>>()?;
        Ok((h, cls))
    }

    /// One local step at slot `cache.len`: change and absolute logits.
    fn local_step(
        &self,
        st: &mut TypedSimpleState,
        cache: &mut Cache,
        ctx: &[f32],
        inp: u32,
        vel: u32,
        prev: u32,
    ) -> Result<(Vec<f32>, Vec<f32>), LmError> {
        let c = self.config();
        let mut inputs: TVec<TValue> = TVec::new();
        inputs.push(
            Tensor::from_shape(&[1, c.d_global], ctx)
                .map_err(rt)?
                .into_tvalue(),
        );
        for id in [inp, vel, prev, cache.len as u32] {
            inputs.push(
                Tensor::from_shape(&[1], &[id as i64])
                    .map_err(rt)?
                    .into_tvalue(),
            );
        }
        inputs.push(cache.bias().into_tvalue());
        cache.inputs(&mut inputs);
        let out = st.run(inputs).map_err(rt)?;
        cache.push(&out[2..])?;
        Ok((floats(&out[0])?.to_vec(), floats(&out[1])?.to_vec()))
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
                let (r, a) = self.local_step(&mut ls, &mut local, &h, inp, vel[s], prev[s])?;
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

    /// Class logits per kind (manifest order) of whole frames of value
    /// tokens (`slots` each), unconditioned: the mean over frames of each
    /// step's class logits (= the head on the mean state).
    pub fn classify(&self, values: &[u32]) -> Result<Vec<Vec<f32>>, LmError> {
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
        let mut sums: Vec<Vec<f32>> = c.classes.iter().map(|(_, v)| vec![0.0; v.len()]).collect();
        for f in 0..n {
            let frame = &values[f * s..(f + 1) * s];
            let p1 = (f > 0).then(|| &values[(f - 1) * s..f * s]);
            let (_, cls) = self.global_step(&mut gs, &mut cache, &cond, Some((frame, p1)))?;
            for (acc, x) in sums.iter_mut().zip(cls) {
                for (a, b) in acc.iter_mut().zip(x) {
                    *a += b / n as f32;
                }
            }
        }
        Ok(sums)
    }
}

/// A running generation with the frame model: caches, the frames in the
/// global window, the last two frames and the random state.
pub struct FrameGenerator {
    session: Arc<FrameSession>,
    gstate: TypedSimpleState,
    lstate: TypedSimpleState,
    cond: Vec<f32>,
    global: Cache,
    /// The next window's cache (the conditioning and the frames that will
    /// be kept at the next slide), filled one frame at a time while the
    /// current window decodes, so a slide costs no burst of work.
    next: Option<Cache>,
    /// Frames in the global cache (after the conditioning row).
    window: Vec<Vec<u32>>,
    /// The frame before the window's first one, if any (its change codes).
    before: Option<Vec<u32>>,
    /// The latest global state: the next frame is decoded from it.
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
        let global = session.new_global_cache();
        let (gstate, lstate) = session.states()?;
        let mut g = FrameGenerator {
            session,
            gstate,
            lstate,
            cond,
            global,
            next: None,
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

    /// Re-encodes the conditioning and the window's frames from an empty
    /// cache.
    fn encode_window(&mut self) -> Result<(), LmError> {
        let s = self.session.clone();
        self.next = None;
        self.global = s.new_global_cache();
        let (h, _) = s.global_step(&mut self.gstate, &mut self.global, &self.cond, None)?;
        self.h = h;
        for i in 0..self.window.len() {
            let p1 = if i == 0 {
                self.before.as_deref()
            } else {
                Some(self.window[i - 1].as_slice())
            };
            let (h, _) = s.global_step(
                &mut self.gstate,
                &mut self.global,
                &self.cond,
                Some((&self.window[i], p1)),
            )?;
            self.h = h;
        }
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
            let (rel, abs) =
                session.local_step(&mut self.lstate, &mut local, &self.h, inp, vel[s], prev[s])?;
            let tok = match forced[s] {
                Some(t) if (t as usize) < c.bins => t,
                Some(t) => {
                    return Err(LmError::invalid(
                        "request",
                        format!("prompt slot {s}"),
                        format!("token {t} is not a value token"),
                    ))
                }
                None => self.draw(c, &rel, &abs, p1.as_ref().map(|p| p[s])),
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
            match self.next.take() {
                Some(n) if n.len == 1 + keep => self.global = n,
                _ => self.encode_window()?,
            }
        }
        let (h, _) = session.global_step(
            &mut self.gstate,
            &mut self.global,
            &self.cond,
            Some((&frame, p1.as_deref())),
        )?;
        self.h = h;
        let i = self.window.len();
        if i >= m - keep {
            if i == m - keep {
                let mut n = session.new_global_cache();
                session.global_step(&mut self.gstate, &mut n, &self.cond, None)?;
                self.next = Some(n);
            }
            if let Some(n) = self.next.as_mut() {
                session.global_step(
                    &mut self.gstate,
                    n,
                    &self.cond,
                    Some((&frame, p1.as_deref())),
                )?;
            }
        }
        self.window.push(frame.clone());
        frame.push(session.manifest.vocabulary.sep());
        self.produced += 1;
        Ok(frame)
    }

    /// A slot's token: a change from the previous frame's token (or an
    /// escape to the absolute head, with the change window masked out);
    /// the absolute head alone when there is no previous frame.
    fn draw(&mut self, c: &FrameConfig, rel: &[f32], abs: &[f32], p1: Option<u32>) -> u32 {
        let Some(p) = p1 else {
            return self.sampling.draw(abs, &mut self.rng) as u32;
        };
        let k = self.sampling.draw(rel, &mut self.rng) as u32;
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
        self.sampling.draw(&masked, &mut self.rng) as u32
    }
}
