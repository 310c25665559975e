//! The frame model on the model runtime (`engine`: tract or ort): two step graphs with static shapes (global and
//! local), fixed-capacity key/value caches written in place, teacher
//! forcing and the unconditioned walk (`classify`, the `lm` embedding).
//! The generator that decodes one frame per call is in
//! [`super::frame_generator`].

use super::engine::{Cache, Engine, Graph, GraphSpec, GraphState, In, Outputs};
use super::frame::{
    frame_changes, global_inputs, global_outputs, local_context, local_inputs, local_outputs,
    FrameConfig, FrameManifest,
};
pub use super::frame_generator::FrameGenerator;
use super::LmError;
use crate::motion::Labels;
use std::path::Path;
use std::sync::Arc;

/// A loaded frame model: the manifest and both graphs, shared by requests.
pub struct FrameSession {
    pub manifest: FrameManifest,
    /// The folder's label postures (`postures.json`), if any.
    pub postures: Option<super::posture::Postures>,
    /// The folder's exemplar spans (`exemplars.json`), if any: what
    /// `sampling.matching` follows.
    pub exemplars: Option<Arc<super::exemplars::Exemplars>>,
    global: Arc<dyn Graph>,
    local: Arc<dyn Graph>,
    local_on: &'static str,
}

/// A global or local run state with its output buffers.
pub(super) struct Step {
    pub(super) st: Box<dyn GraphState>,
    pub(super) out: Outputs,
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
                batch: None,
            },
        )?;
        let local = engine.load(
            &l,
            &GraphSpec {
                inputs: &local_inputs(c),
                outputs: local_outputs(c).len(),
                file: &name(&manifest.local_onnx),
                f32_shapes: &[],
                batch: Some(super::frame::LOCAL_BATCH),
            },
        )?;
        // The local step on choreo's kernel where it reproduces the graph
        // (checked on probe steps at every load), else on the runtime.
        let (local, local_on) = if engine.local_step() == super::engine::LocalStep::Kernel {
            match super::engine::local_kernel::checked(
                local.as_ref(),
                &l,
                (c.local_layers, c.local_heads, c.ln_eps as f32),
            ) {
                Ok((k, diff)) => {
                    tracing::info!(
                        "{}: local step on choreo's kernel (probe within {diff:e} of the graph)",
                        name(&manifest.local_onnx)
                    );
                    (Arc::new(k) as Arc<dyn Graph>, "kernel")
                }
                Err(why) => {
                    tracing::warn!(
                        "{}: the local step stays on {}: {why} (`choreo-train upgrade-frame --model DIR` rewrites an older local graph in today's form)",
                        name(&manifest.local_onnx),
                        engine.runtime().name()
                    );
                    (local, engine.runtime().name())
                }
            }
        } else {
            (local, engine.runtime().name())
        };
        let postures = super::posture::Postures::load(path, &manifest.vocabulary)?;
        let exemplars =
            super::exemplars::Exemplars::load(path, &manifest.vocabulary)?.map(Arc::new);
        if postures.is_none() {
            if let Some(kind) = manifest
                .sampling_by_kind
                .iter()
                .find(|(_, d)| d.posture.is_some_and(|w| w > 0.0))
                .map(|(k, _)| k)
            {
                return Err(super::LmError::invalid(
                    &name("manifest.json"),
                    format!("sampling_by_kind.{kind}.posture"),
                    "the folder has no postures.json to pull toward (choreo postures writes one)",
                ));
            }
        }
        Ok(FrameSession {
            manifest,
            postures,
            exemplars,
            global,
            local,
            local_on,
        })
    }

    /// What runs the local step: `kernel` (choreo's), else the runtime's
    /// name.
    pub fn local_step_on(&self) -> &'static str {
        self.local_on
    }

    pub fn config(&self) -> &FrameConfig {
        &self.manifest.config
    }

    /// Fresh run states for the global and local plans (one pair per
    /// generator: their buffers are reused from step to step).
    pub(super) fn states(&self) -> Result<(Step, Step), LmError> {
        let step = |g: &Arc<dyn Graph>| -> Result<Step, LmError> {
            Ok(Step {
                st: g.spawn()?,
                out: Outputs::default(),
            })
        };
        Ok((step(&self.global)?, step(&self.local)?))
    }

    pub(super) fn new_global_cache(&self) -> Cache {
        let c = self.config();
        Cache::new(
            c.global_layers,
            c.global_heads,
            c.max_frames + 1,
            c.d_global / c.global_heads,
        )
    }

    /// A run state for `n` candidate frames decoded side by side, if the
    /// local graph has a batch dimension (exported since it has one);
    /// None for an older graph.
    pub(super) fn local_batch(&self, n: usize) -> Result<Option<Step>, LmError> {
        Ok(self.local.spawn_batch(n)?.map(|st| Step {
            st,
            out: Outputs::default(),
        }))
    }

    /// Whether the local graph decodes candidate frames side by side (it
    /// was exported with the batch dimension).
    pub fn batches(&self) -> bool {
        self.local.batches()
    }

    /// The local caches of `n` candidates side by side.
    pub(super) fn new_local_caches(&self, n: usize) -> Cache {
        let c = self.config();
        Cache::batched(
            n,
            c.local_layers,
            c.local_heads,
            c.slots,
            c.d_local / c.local_heads,
        )
    }

    pub(super) fn new_local_cache(&self) -> Cache {
        self.new_local_caches(1)
    }

    /// One global step: the conditioning (`frame` = None) or one frame of
    /// value tokens after `p1`. Returns the state and the class logits.
    pub(super) fn global_step(
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

    /// One local step at slot `cache.len()` for `inp.len()` rows side by
    /// side (candidate frames; one on a graph without the batch
    /// dimension), all under the global state `ctx` with the slot's `vel`
    /// and `prev`: row b's change logits are `st.out.data(0)`'s b-th
    /// `rel_classes()` row, its absolute logits `data(1)`'s b-th `bins`
    /// row.
    pub(super) fn local_step(
        &self,
        st: &mut Step,
        cache: &mut Cache,
        ctx: &[f32],
        inp: &[i64],
        vel: u32,
        prev: u32,
    ) -> Result<(), LmError> {
        let c = self.config();
        let n = inp.len();
        let bias = cache.bias();
        let ctxs: std::borrow::Cow<[f32]> = if n == 1 {
            ctx.into()
        } else {
            (0..n).flat_map(|_| ctx.iter().copied()).collect()
        };
        let (vels, prevs) = (vec![vel as i64; n], vec![prev as i64; n]);
        let slot = [cache.len() as i64];
        let inputs = [
            In::F32(&[n, c.d_global], &ctxs),
            In::I64(&[n], inp),
            In::I64(&[n], &vels),
            In::I64(&[n], &prevs),
            In::I64(&[1], &slot),
            In::F32(&[1, bias.len()], bias),
        ];
        st.st.run(&inputs, Some(cache), &mut st.out)?;
        cache.push(&st.out, 2)
    }

    /// Decodes the slots of `rows.len()` frames side by side under the
    /// global state `ctx` after `p1` (`vel`, `prev`: the slots' local
    /// context), one local run a slot: `st` holds a plan for that many
    /// rows. Each row's slot token comes from `token(b, s, logits)` (the
    /// row's change and absolute logits; a teacher's token, or a draw),
    /// which may also record them; it is appended to `rows[b]`.
    pub(super) fn decode_rows(
        &self,
        st: &mut Step,
        ctx: &[f32],
        (vel, prev, p1): (&[u32], &[u32], Option<&[u32]>),
        rows: &mut [Vec<u32>],
        mut token: impl FnMut(usize, usize, (&[f32], &[f32]), &[u32]) -> Result<u32, LmError>,
    ) -> Result<(), LmError> {
        let c = self.config();
        let n = rows.len();
        let mut cache = self.new_local_caches(n);
        let mut inp = vec![c.start() as i64; n];
        let (rc, bins) = (c.rel_classes(), c.bins);
        for s in 0..c.slots {
            self.local_step(st, &mut cache, ctx, &inp, vel[s], prev[s])?;
            for (b, row) in rows.iter_mut().enumerate() {
                let logits = (
                    &st.out.data(0)[b * rc..(b + 1) * rc],
                    &st.out.data(1)[b * bins..(b + 1) * bins],
                );
                let t = token(b, s, logits, row)?;
                inp[b] = c.change(p1.map(|p| p[s]), t) as i64;
                row.push(t);
            }
        }
        Ok(())
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
        let mut step = |local: &mut Cache| {
            let r0 = c.radius;
            self.local_step(&mut ls, local, &h, &[r0 as i64], r0 as u32, 0)
        };
        for _ in 0..c.slots / 2 {
            step(&mut local)?;
        }
        for _ in 0..repeats {
            let t = std::time::Instant::now();
            step(&mut local)?;
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
            out.push(self.logits_along(&mut ls, &h, (p1, p2), frame)?);
            h = self
                .global_step(&mut gs, &mut cache, cond, Some((frame, p1)))?
                .0;
        }
        Ok(out)
    }

    /// The global state after the conditioning row `cond` and `frames`
    /// (value tokens from a sequence's start, at most the context).
    pub fn state_after(&self, cond: &[f32], frames: &[Vec<u32>]) -> Result<Vec<f32>, LmError> {
        let (mut gs, _) = self.states()?;
        let mut cache = self.new_global_cache();
        let (mut h, _) = self.global_step(&mut gs, &mut cache, cond, None)?;
        for (f, frame) in frames.iter().enumerate() {
            let p1 = (f > 0).then(|| frames[f - 1].as_slice());
            h = self
                .global_step(&mut gs, &mut cache, cond, Some((frame, p1)))?
                .0;
        }
        Ok(h)
    }

    /// The local decoder's logits (per candidate, change and absolute
    /// logits of every slot, row-major) for the candidate frames `cands`
    /// (value tokens, `slots` each) after `p1` and `p2`, under the global
    /// state `ctx`: side by side in one batched run a slot where the graph
    /// has a batch dimension and `batched`, else one candidate at a time.
    /// Errors if `batched` is asked of a graph without one. The two must
    /// agree (the frame model's export test checks it).
    pub fn local_logits(
        &self,
        ctx: &[f32],
        (p1, p2): (Option<&[u32]>, Option<&[u32]>),
        cands: &[Vec<u32>],
        batched: bool,
    ) -> Result<Vec<(Vec<f32>, Vec<f32>)>, LmError> {
        if !batched {
            let (_, mut st) = self.states()?;
            return cands
                .iter()
                .map(|f| self.logits_along(&mut st, ctx, (p1, p2), f))
                .collect();
        }
        let mut st = self
            .local_batch(cands.len())?
            .ok_or_else(|| LmError::Runtime("the local graph has no batch dimension".into()))?;
        let (vel, prev) = local_context(self.config(), p1, p2);
        let mut out = vec![(Vec::new(), Vec::new()); cands.len()];
        let mut rows = vec![Vec::new(); cands.len()];
        self.decode_rows(
            &mut st,
            ctx,
            (&vel, &prev, p1),
            &mut rows,
            |b, s, (r, a), _| {
                out[b].0.extend_from_slice(r);
                out[b].1.extend_from_slice(a);
                Ok(cands[b][s])
            },
        )?;
        Ok(out)
    }

    /// One frame's local logits (change, absolute; every slot) with the
    /// frame's own tokens fed back (teacher forcing), on a one-row state.
    fn logits_along(
        &self,
        st: &mut Step,
        ctx: &[f32],
        (p1, p2): (Option<&[u32]>, Option<&[u32]>),
        frame: &[u32],
    ) -> Result<(Vec<f32>, Vec<f32>), LmError> {
        let (vel, prev) = local_context(self.config(), p1, p2);
        let (mut r, mut a) = (Vec::new(), Vec::new());
        let mut row = [Vec::new()];
        self.decode_rows(st, ctx, (&vel, &prev, p1), &mut row, |_, s, (x, y), _| {
            r.extend_from_slice(x);
            a.extend_from_slice(y);
            Ok(frame[s])
        })?;
        Ok((r, a))
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
