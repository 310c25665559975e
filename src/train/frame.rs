//! The frame-level motion model in candle (see `lm::frame` for the design):
//! its parameters, forward pass, examples and batches, and losses. The
//! training loop, evaluation and checkpoints are in `frame_run`; where a
//! run starts from (checkpoint or export) and its lineage in `frame_init`.

pub use super::frame_init::{init_source, licences_with_parents, lineage_seconds, net_from_export};
pub use super::frame_run::{
    evaluate, load, run, table, train_step, FrameData, FrameEval, FrameRun, FrameState,
};
use super::model::{filled, insert_stack, normal, Params};
use crate::lm::frame::{frame_changes, local_context, FrameConfig};
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use anyhow::Result;
use candle_core::{Device, Tensor, D};
use rand::rngs::StdRng;
use rand::Rng;
use std::collections::BTreeMap;

/// The network: its configuration and named parameters.
pub struct FrameNet {
    pub cfg: FrameConfig,
    pub params: Params,
}

/// A causal additive bias `[1, 1, n, n]`.
fn causal(n: usize, dev: &Device) -> candle_core::Result<Tensor> {
    let v: Vec<f32> = (0..n * n)
        .map(|i| if i % n > i / n { -1e9 } else { 0.0 })
        .collect();
    Tensor::from_vec(v, (1, 1, n, n), dev)
}

impl FrameNet {
    pub fn new(cfg: FrameConfig, dev: &Device) -> candle_core::Result<FrameNet> {
        let (dg, dl, de) = (cfg.d_global, cfg.d_local, cfg.d_emb);
        let mut p = BTreeMap::new();
        p.insert("g_val".into(), normal(&[cfg.bins, de], 0.02, dev)?);
        p.insert("g_chg".into(), normal(&[cfg.change_rows(), de], 0.02, dev)?);
        p.insert("g_in.w".into(), normal(&[cfg.slots * de, dg], 0.02, dev)?);
        p.insert("g_in.b".into(), filled(&[dg], 0.0, dev)?);
        p.insert("g_cond".into(), normal(&[cfg.vocab_size, dg], 0.02, dev)?);
        if cfg.cond_every {
            // Zero at the start: the per-frame label path begins silent, so
            // a model warm-started from one without it (`--init-from`)
            // resumes exactly where its parent ended.
            p.insert(
                "g_cond_all".into(),
                filled(&[cfg.vocab_size, dg], 0.0, dev)?,
            );
        }
        p.insert(
            "g_pos".into(),
            normal(&[cfg.max_frames + 1, dg], 0.02, dev)?,
        );
        insert_stack(&mut p, "g", cfg.global_layers, dg, 4 * dg, dev)?;
        p.insert("g_ln.w".into(), filled(&[dg], 1.0, dev)?);
        p.insert("g_ln.b".into(), filled(&[dg], 0.0, dev)?);
        p.insert("l_ctx.w".into(), normal(&[dg, dl], 0.02, dev)?);
        p.insert("l_ctx.b".into(), filled(&[dl], 0.0, dev)?);
        p.insert("l_in".into(), normal(&[cfg.change_rows(), dl], 0.02, dev)?);
        p.insert("l_vel".into(), normal(&[cfg.change_rows(), dl], 0.02, dev)?);
        p.insert("l_prev".into(), normal(&[cfg.bins + 1, dl], 0.02, dev)?);
        p.insert("l_pos".into(), normal(&[cfg.slots, dl], 0.02, dev)?);
        insert_stack(&mut p, "l", cfg.local_layers, dl, 4 * dl, dev)?;
        p.insert("l_ln.w".into(), filled(&[dl], 1.0, dev)?);
        p.insert("l_ln.b".into(), filled(&[dl], 0.0, dev)?);
        p.insert("rel.w".into(), normal(&[dl, cfg.rel_classes()], 0.02, dev)?);
        p.insert("rel.b".into(), filled(&[cfg.rel_classes()], 0.0, dev)?);
        p.insert("abs.w".into(), normal(&[dl, cfg.bins], 0.02, dev)?);
        p.insert("abs.b".into(), filled(&[cfg.bins], 0.0, dev)?);
        for (k, values) in &cfg.classes {
            p.insert(
                format!("cls.{k}.w"),
                normal(&[dg, values.len()], 0.02, dev)?,
            );
            p.insert(format!("cls.{k}.b"), filled(&[values.len()], 0.0, dev)?);
        }
        Ok(FrameNet {
            cfg,
            params: Params(p),
        })
    }

    fn emb(&self, table: &str, ids: &Tensor) -> candle_core::Result<Tensor> {
        let mut shape = ids.dims().to_vec();
        let w = self.params.w(table);
        shape.push(w.dim(1)?);
        w.index_select(&ids.flatten_all()?, 0)?.reshape(shape)
    }

    /// Global states `[B, T + 1, d_global]` (after the final norm): position
    /// 0 is the conditioning, position `t + 1` frame `t`. `val`, `chg`:
    /// `[B, T, slots]` u32; `cond`: `[B, vocab]` f32 multi-hot.
    pub fn global(&self, val: &Tensor, chg: &Tensor, cond: &Tensor) -> candle_core::Result<Tensor> {
        let c = &self.cfg;
        let (b, t, s) = val.dims3()?;
        let e =
            (self.emb("g_val", val)? + self.emb("g_chg", chg)?)?.reshape((b, t, s * c.d_emb))?;
        let mut frames = self.params.lin(&e, "g_in")?;
        if c.cond_every {
            let every = cond.matmul(self.params.w("g_cond_all"))?.unsqueeze(1)?;
            frames = frames.broadcast_add(&every)?;
        }
        let cond = cond.matmul(self.params.w("g_cond"))?.unsqueeze(1)?;
        let x = Tensor::cat(&[&cond, &frames], 1)?;
        let pos = self.params.w("g_pos").narrow(0, 0, t + 1)?;
        let mut x = x.broadcast_add(&pos)?;
        let bias = causal(t + 1, val.device())?;
        for l in 0..c.global_layers {
            x = self
                .params
                .block(&x, &format!("g{l}"), c.global_heads, c.ln_eps, Some(&bias))?;
        }
        self.params.ln(&x, "g_ln", c.ln_eps)
    }

    /// Change and absolute logits `[N, slots, rel]`, `[N, slots, bins]` for
    /// `N` frames, each decoded from its global state `ctx: [N, d_global]`;
    /// `inp`, `vel`, `prev`: `[N, slots]` u32.
    pub fn local(
        &self,
        ctx: &Tensor,
        inp: &Tensor,
        vel: &Tensor,
        prev: &Tensor,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let x = self.local_states(ctx, inp, vel, prev)?;
        Ok((self.params.lin(&x, "rel")?, self.params.lin(&x, "abs")?))
    }

    /// The local decoder's normed states `[N, slots, d_local]`, which the
    /// change (`rel`) and absolute (`abs`) heads read.
    pub fn local_states(
        &self,
        ctx: &Tensor,
        inp: &Tensor,
        vel: &Tensor,
        prev: &Tensor,
    ) -> candle_core::Result<Tensor> {
        let c = &self.cfg;
        let s = inp.dim(1)?;
        let ctx = self.params.lin(ctx, "l_ctx")?.unsqueeze(1)?;
        let x =
            ((self.emb("l_in", inp)? + self.emb("l_vel", vel)?)? + self.emb("l_prev", prev)?)?;
        let pos = self.params.w("l_pos").narrow(0, 0, s)?;
        let mut x = x.broadcast_add(&ctx)?.broadcast_add(&pos)?;
        let bias = causal(s, inp.device())?;
        for l in 0..c.local_layers {
            x = self
                .params
                .block(&x, &format!("l{l}"), c.local_heads, c.ln_eps, Some(&bias))?;
        }
        self.params.ln(&x, "l_ln", c.ln_eps)
    }

    /// Class logits per kind `[B, classes]` from the frames' global states
    /// averaged under `frame_w: [B, T]`.
    pub fn classify(&self, h: &Tensor, frame_w: &Tensor) -> candle_core::Result<Vec<Tensor>> {
        let t = frame_w.dim(1)?;
        let hs = h.narrow(1, 1, t)?;
        let w = frame_w.unsqueeze(2)?;
        let pooled = hs
            .broadcast_mul(&w)?
            .sum(1)?
            .broadcast_div(&w.sum(1)?.clamp(1e-6, f64::MAX)?)?;
        self.cfg
            .classes
            .iter()
            .map(|(k, _)| self.params.lin(&pooled, &format!("cls.{k}")))
            .collect()
    }
}

/// One window for training or evaluation.
pub struct FrameExample {
    /// `T × slots` value tokens.
    pub frames: Vec<u32>,
    /// The window's previous two frames (most recent first), where the
    /// sequence has them.
    pub hist: Vec<Vec<u32>>,
    /// Conditioning token ids (`<bos>` and kept labels).
    pub cond: Vec<u32>,
    /// Class targets: (kind index, class index).
    pub classes: Vec<(usize, usize)>,
    /// The frames and history as the network reads them when they differ
    /// from the true ones ([`add_context_noise`], [`add_own_samples`]);
    /// the targets are always `frames`.
    pub context: Option<(Vec<u32>, Vec<Vec<u32>>)>,
}

/// Puts context noise on an example: draws a level `σ` uniformly in
/// `[0, max_bins]` and moves every slot of every frame and history frame
/// the network reads by a rounded `N(0, σ²)` number of bins (angle slots
/// wrap round, the others are clamped into the bins). The frames stay the
/// targets, so the change the model learns to name is the true next frame
/// against the noisy previous one: it learns to continue from imperfect
/// history and steer back, as it must from its own samples (exposure
/// bias). `max_bins` 0 leaves the example clean.
pub fn add_context_noise(
    cfg: &FrameConfig,
    ex: &mut FrameExample,
    max_bins: f64,
    rng: &mut StdRng,
) {
    if max_bins <= 0.0 {
        return;
    }
    let sigma = rng.gen::<f64>() * max_bins;
    let s = cfg.slots;
    let bins = cfg.bins as i64;
    let noisy = |v: &[u32], rng: &mut StdRng| -> Vec<u32> {
        v.iter()
            .enumerate()
            .map(|(i, &x)| {
                let d = (crate::motion::keypoints::gaussian(rng) * sigma).round() as i64;
                let y = x as i64 + d;
                let y = if cfg.wraps(i % s) {
                    y.rem_euclid(bins)
                } else {
                    y.clamp(0, bins - 1)
                };
                y as u32
            })
            .collect()
    };
    let frames = noisy(&ex.frames, rng);
    let hist = ex.hist.iter().map(|h| noisy(h, rng)).collect();
    ex.context = Some((frames, hist));
}

/// Puts the model's own one-step samples into the context (parallel
/// scheduled sampling): one pass over the batch as the network would read
/// it gives every frame's change distribution given the history; each
/// slot's change is drawn from it (temperature 1) and, for a share
/// `share` of the frames with a previous frame, the drawn frame replaces
/// what the network reads there (a slot whose draw is the escape keeps
/// its value; a change is clamped into the bins, as the generator does). The targets stay the true frames, so the second pass
/// teaches the model to go on from its own kind of errors, as it must
/// when it generates. `share` 0 leaves the examples as they are.
pub fn add_own_samples(
    net: &FrameNet,
    exs: &mut [FrameExample],
    share: f64,
    rng: &mut StdRng,
    dev: &Device,
) -> Result<()> {
    if share <= 0.0 || exs.is_empty() {
        return Ok(());
    }
    let c = &net.cfg;
    let s = c.slots;
    let b = batch(c, exs, dev)?;
    let h = net.global(&b.val, &b.chg, &b.cond)?;
    let (bs, t1, dg) = h.dims3()?;
    let t = t1 - 1;
    let ctx = h.narrow(1, 0, t)?.reshape((bs * t, dg))?;
    let x = net.local_states(&ctx, &b.inp, &b.vel, &b.prev)?;
    let x = x.reshape((bs * t * s, c.d_local))?;
    let logits = net
        .params
        .lin(&x, "rel")?
        .to_dtype(candle_core::DType::F32)?
        .to_vec2::<f32>()?;
    let plain = crate::lm::Sampling {
        temperature: 1.0,
        ..Default::default()
    };
    for (i, e) in exs.iter_mut().enumerate() {
        let (mut seen, hist) = match e.context.take() {
            Some(x) => x,
            None => (e.frames.clone(), e.hist.clone()),
        };
        let read = seen.clone();
        let nf = e.frames.len() / s;
        for f in 0..nf {
            if rng.gen::<f64>() >= share {
                continue;
            }
            let p1: &[u32] = match f {
                0 => match hist.first() {
                    Some(p) => p,
                    None => continue,
                },
                _ => &read[(f - 1) * s..f * s],
            };
            for k in 0..s {
                let code = plain.draw(&logits[(i * t + f) * s + k], rng) as u32;
                if let Some(b) = c.apply_change(p1[k], code) {
                    seen[f * s + k] = b;
                }
            }
        }
        e.context = Some((seen, hist));
    }
    Ok(())
}

/// Value slots of whole frames (the separator dropped).
pub fn value_frames(tokens: &[u32], fl: usize) -> Vec<u32> {
    tokens
        .chunks_exact(fl)
        .flat_map(|f| f[..fl - 1].iter().copied())
        .collect()
}

/// The share of training windows (models with `cond_every`, labels kept
/// with probability below 1) whose labels are all dropped, so the model also learns the unconditioned
/// distribution that classifier-free guidance steers away from.
pub const UNCONDITIONED: f64 = 0.2;

/// The window `[start, start + len)` of a sequence's value frames, with
/// its history, conditioned on `labels` (each kept with `keep_label`) or,
/// for classification, on `<bos>` alone with the class targets.
#[allow(clippy::too_many_arguments)]
pub fn example(
    cfg: &FrameConfig,
    vocab: &Vocabulary,
    values: &[u32],
    start: usize,
    len: usize,
    labels: &Labels,
    as_classifier: bool,
    keep_label: f64,
    rng: &mut StdRng,
) -> FrameExample {
    let s = cfg.slots;
    let frame = |f: usize| values[f * s..(f + 1) * s].to_vec();
    let hist = (1..=2)
        .filter(|&k| start >= k)
        .map(|k| frame(start - k))
        .collect();
    let mut cond = vec![vocab.bos()];
    let mut classes = Vec::new();
    if as_classifier {
        for (ci, (k, vs)) in cfg.classes.iter().enumerate() {
            if let Some(idx) = labels.get(k).and_then(|v| vs.iter().position(|x| x == v)) {
                classes.push((ci, idx));
            }
        }
    } else if !(cfg.cond_every && keep_label < 1.0 && rng.gen::<f64>() < UNCONDITIONED) {
        for k in &cfg.cond_kinds {
            if let Some(v) = labels.get(k) {
                if rng.gen::<f64>() < keep_label {
                    if let Ok(t) = vocab.label_token(k, v) {
                        cond.push(t);
                    }
                }
            }
        }
    }
    FrameExample {
        frames: values[start * s..(start + len) * s].to_vec(),
        hist,
        cond,
        classes,
        context: None,
    }
}

/// A batch as tensors.
pub struct FrameBatch {
    pub val: Tensor,
    pub chg: Tensor,
    pub cond: Tensor,
    pub inp: Tensor,
    pub vel: Tensor,
    pub prev: Tensor,
    pub rel_t: Tensor,
    pub rel_w: Tensor,
    /// The slots the absolute head is scored on (a sequence's first frame,
    /// and escapes from the change window), as rows of the flattened
    /// `[B · T · slots]` slots, and their targets; `None` when there are
    /// none. Only these rows' absolute logits are computed: the others
    /// would carry zero weight (most of a step's work, at 360 bins).
    pub abs_rows: Option<(Tensor, Tensor)>,
    pub frame_w: Tensor,
    /// Per class kind: (batch rows, class indices).
    pub classes: Vec<Option<(Tensor, Tensor)>>,
    pub frames: usize,
    pub t: usize,
}

pub fn batch<'a>(cfg: &FrameConfig, exs: &'a [FrameExample], dev: &Device) -> Result<FrameBatch> {
    let s = cfg.slots;
    let b = exs.len();
    let t = exs
        .iter()
        .map(|e| e.frames.len() / s)
        .max()
        .unwrap_or(1)
        .max(1);
    let n = b * t * s;
    let mut val = vec![0u32; n];
    let mut chg = vec![cfg.none(); n];
    let mut inp = vec![cfg.start(); n];
    let mut vel = vec![cfg.none(); n];
    let mut prev = vec![cfg.bins as u32; n];
    let (mut rel_t, mut rel_w) = (vec![0u32; n], vec![0f32; n]);
    let (mut abs_rows, mut abs_t) = (Vec::new(), Vec::new());
    let mut frame_w = vec![0f32; b * t];
    let mut cond = vec![0f32; b * cfg.vocab_size];
    let mut cls: Vec<(Vec<u32>, Vec<u32>)> = vec![(Vec::new(), Vec::new()); cfg.classes.len()];
    let mut frames = 0;
    for (i, e) in exs.iter().enumerate() {
        for &c in &e.cond {
            cond[i * cfg.vocab_size + c as usize] = 1.0;
        }
        for &(ci, idx) in &e.classes {
            cls[ci].0.push(i as u32);
            cls[ci].1.push(idx as u32);
        }
        let nf = e.frames.len() / s;
        let at = |frames: &'a [u32], hist: &'a [Vec<u32>], f: isize| -> Option<&'a [u32]> {
            if f >= 0 {
                Some(&frames[f as usize * s..(f as usize + 1) * s])
            } else {
                hist.get((-f - 1) as usize).map(|v| v.as_slice())
            }
        };
        // What the network reads (noisy under context noise) and what it
        // is scored on (always the true frame).
        let (cf, ch) = match &e.context {
            Some((f, h)) => (f.as_slice(), h.as_slice()),
            None => (e.frames.as_slice(), e.hist.as_slice()),
        };
        for f in 0..nf {
            frames += 1;
            frame_w[i * t + f] = 1.0;
            let cur = at(&e.frames, &e.hist, f as isize).expect("in window");
            let seen = at(cf, ch, f as isize).expect("in window");
            let p1 = at(cf, ch, f as isize - 1);
            let p2 = at(cf, ch, f as isize - 2);
            let changes = frame_changes(cfg, cur, p1);
            let noisy_changes;
            let seen_changes = if e.context.is_some() {
                noisy_changes = frame_changes(cfg, seen, p1);
                &noisy_changes
            } else {
                &changes
            };
            let (v, p) = local_context(cfg, p1, p2);
            let base = (i * t + f) * s;
            for k in 0..s {
                val[base + k] = seen[k];
                chg[base + k] = seen_changes[k];
                vel[base + k] = v[k];
                prev[base + k] = p[k];
                if k > 0 {
                    inp[base + k] = changes[k - 1];
                }
                let scored_abs = match p1 {
                    None => true,
                    Some(_) => {
                        rel_t[base + k] = changes[k];
                        rel_w[base + k] = 1.0;
                        changes[k] == cfg.esc()
                    }
                };
                if scored_abs {
                    abs_rows.push((base + k) as u32);
                    abs_t.push(cur[k]);
                }
            }
        }
    }
    let u = |v: Vec<u32>| Tensor::from_vec(v, (b, t, s), dev);
    let classes = cls
        .into_iter()
        .map(|(rows, idx)| -> Result<Option<(Tensor, Tensor)>> {
            if rows.is_empty() {
                return Ok(None);
            }
            let k = rows.len();
            Ok(Some((
                Tensor::from_vec(rows, k, dev)?,
                Tensor::from_vec(idx, k, dev)?,
            )))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(FrameBatch {
        val: u(val)?,
        chg: u(chg)?,
        cond: Tensor::from_vec(cond, (b, cfg.vocab_size), dev)?,
        inp: Tensor::from_vec(inp, (b * t, s), dev)?,
        vel: Tensor::from_vec(vel, (b * t, s), dev)?,
        prev: Tensor::from_vec(prev, (b * t, s), dev)?,
        rel_t: Tensor::from_vec(rel_t, n, dev)?,
        rel_w: Tensor::from_vec(rel_w, n, dev)?,
        abs_rows: if abs_rows.is_empty() {
            None
        } else {
            let k = abs_rows.len();
            Some((
                Tensor::from_vec(abs_rows, k, dev)?,
                Tensor::from_vec(abs_t, k, dev)?,
            ))
        },
        frame_w: Tensor::from_vec(frame_w, (b, t), dev)?,
        classes,
        frames,
        t,
    })
}

/// Summed negative log-likelihood of `targets` under `logits: [N, C]`,
/// weighted per row.
fn weighted_nll(logits: &Tensor, targets: &Tensor, w: &Tensor) -> candle_core::Result<Tensor> {
    let lsm = candle_nn::ops::log_softmax(logits, D::Minus1)?;
    let picked = lsm.gather(&targets.unsqueeze(1)?, 1)?.squeeze(1)?;
    (picked * w)?.sum_all()?.neg()
}

/// What one batch costs.
pub struct FrameLosses {
    /// Summed nats over the batch's frames (the language model).
    pub nats: Tensor,
    /// Summed class cross-entropies (mean over rows per kind), if any.
    pub cls: Option<Tensor>,
    /// Per class kind: (hits, rows).
    pub hits: Vec<(usize, usize)>,
}

pub fn losses(net: &FrameNet, b: &FrameBatch) -> Result<FrameLosses> {
    let c = &net.cfg;
    let h = net.global(&b.val, &b.chg, &b.cond)?;
    let (bs, t1, dg) = h.dims3()?;
    let t = t1 - 1;
    let ctx = h.narrow(1, 0, t)?.reshape((bs * t, dg))?;
    let x = net.local_states(&ctx, &b.inp, &b.vel, &b.prev)?;
    let n = bs * t * c.slots;
    let x = x.reshape((n, c.d_local))?;
    let rel = net.params.lin(&x, "rel")?;
    let mut nats = weighted_nll(&rel, &b.rel_t, &b.rel_w)?;
    if let Some((rows, targets)) = &b.abs_rows {
        let abs = net.params.lin(&x.index_select(rows, 0)?, "abs")?;
        let lsm = candle_nn::ops::log_softmax(&abs, D::Minus1)?;
        let picked = lsm.gather(&targets.unsqueeze(1)?, 1)?;
        nats = (nats - picked.sum_all()?)?;
    }
    let mut cls: Option<Tensor> = None;
    let mut hits = Vec::new();
    if !c.classes.is_empty() && b.classes.iter().any(|x| x.is_some()) {
        let logits = net.classify(&h, &b.frame_w)?;
        for (k, lg) in logits.iter().enumerate() {
            let Some((rows, idx)) = &b.classes[k] else {
                hits.push((0, 0));
                continue;
            };
            let (l, h) = super::class_loss(&lg.index_select(rows, 0)?, idx)?;
            hits.push(h);
            cls = Some(match cls {
                Some(a) => (a + l)?,
                None => l,
            });
        }
    }
    Ok(FrameLosses { nats, cls, hits })
}
