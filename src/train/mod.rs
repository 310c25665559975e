//! The offline trainer (feature `train`): data, the candle GPT, the loop
//! with checkpoints and validation, the learning-rate sweep, the ONNX
//! export and the classification baselines.

pub mod baselines;
pub mod data;
pub mod draws;
pub mod export;
pub mod flat_run;
pub mod frame;
pub mod frame_export;
pub mod frame_heads;
pub mod frame_init;
pub mod frame_run;
pub mod fused;
pub mod inbetween;
pub mod model;
pub mod parity;
pub use draws::cumulative;

use crate::lm::{bits_per_frame, ModelConfig};
use crate::tokenize::vocab::Vocabulary;
use anyhow::{bail, Context, Result};
use candle_core::{Device, Tensor, D};
use data::{Batch, Corpus, Example, ExampleOptions};
use model::{AdamW, Gpt};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Hyper-parameters of a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunSettings {
    pub steps: usize,
    pub batch: usize,
    pub lr: f64,
    pub min_lr_ratio: f64,
    pub warmup: usize,
    pub weight_decay: f64,
    pub dropout: f32,
    pub eval_every: usize,
    pub seed: u64,
    pub keep_label: f64,
    pub classify_fraction: f64,
    pub class_weight: f64,
    pub mask_rate: f64,
    /// Stop after this many seconds of training (0 = no limit).
    pub max_seconds: f64,
    /// How often a corpus's frames are drawn relative to the others (frame
    /// model; a corpus not named keeps 1). Empty = length-weighted draws.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub corpus_weights: BTreeMap<String, f64>,
    /// Frame model: draw the training sequences so that every value of
    /// this label kind gets the same share (None = length-weighted).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub balance: Option<String>,
    /// Frame model: the largest noise (in bins, a standard deviation) put
    /// on the context frames the network reads while the targets stay the
    /// true frames, so it learns to go on from imperfect history, as it
    /// must from its own samples (0 = clean context; see
    /// `frame::add_context_noise`).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub context_noise: f64,
    /// Frame model: the share of context frames replaced by the model's
    /// own one-step samples before each step (parallel scheduled
    /// sampling; `frame::add_own_samples`); 0 = off.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub own_context: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// One logged point.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LogPoint {
    pub step: usize,
    pub lr: f64,
    pub train_loss: f64,
    pub val_loss: Option<f64>,
    pub val_bits_per_frame: Option<f64>,
    pub tokens_per_s: f64,
}

/// What a checkpoint's JSON side holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CheckpointState {
    pub config: ModelConfig,
    pub vocabulary: Vocabulary,
    pub settings: RunSettings,
    pub step: usize,
    pub adam_step: usize,
    pub history: Vec<LogPoint>,
    pub regime: String,
    pub parent: Option<String>,
    pub data: crate::lm::manifest::DataInfo,
    pub metrics: BTreeMap<String, f64>,
}

pub const CKPT_JSON: &str = "checkpoint.json";
pub const CKPT_WEIGHTS: &str = "checkpoint.safetensors";

pub fn save_checkpoint(
    dir: &Path,
    model: &Gpt,
    opt: &AdamW,
    state: &CheckpointState,
) -> Result<()> {
    save_parts(dir, &model.params, opt, state)
}

/// Writes parameters, optimiser moments and a JSON state as one checkpoint
/// folder (each file written beside, then renamed).
pub fn save_parts(
    dir: &Path,
    params: &model::Params,
    opt: &AdamW,
    state: &impl Serialize,
) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut t: HashMap<String, Tensor> = params.tensors().into_iter().collect();
    for (k, m) in &opt.m {
        t.insert(format!("adam.m.{k}"), m.clone());
    }
    for (k, v) in &opt.v {
        t.insert(format!("adam.v.{k}"), v.clone());
    }
    // Write beside, then rename: a crash never leaves half a checkpoint.
    let tmp = dir.join(format!("{CKPT_WEIGHTS}.tmp"));
    candle_core::safetensors::save(&t, &tmp)?;
    std::fs::rename(&tmp, dir.join(CKPT_WEIGHTS))?;
    let js = dir.join(format!("{CKPT_JSON}.tmp"));
    std::fs::write(&js, serde_json::to_string_pretty(state)?)?;
    std::fs::rename(&js, dir.join(CKPT_JSON))?;
    Ok(())
}

/// Loads a checkpoint folder: the state, the model and the optimiser.
/// Missing or corrupt files are errors naming them.
pub fn load_checkpoint(dir: &Path, dev: &Device) -> Result<(CheckpointState, Gpt, AdamW)> {
    let (state, t, file): (CheckpointState, _, _) = load_parts(dir, dev)?;
    state
        .config
        .validate(&dir.join(CKPT_JSON).display().to_string())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let model = Gpt::new(state.config.clone(), state.settings.dropout, dev)?;
    model.params.load_tensors(&t, &file)?;
    let opt = restore_adam(&t, &state.settings, state.adam_step);
    Ok((state, model, opt))
}

/// Reads a checkpoint folder's JSON state and tensors (weights and
/// optimiser moments); returns them with the weights file's name for
/// errors. Missing or corrupt files are errors naming them.
pub fn load_parts<S: serde::de::DeserializeOwned>(
    dir: &Path,
    dev: &Device,
) -> Result<(S, BTreeMap<String, Tensor>, String)> {
    let jp = dir.join(CKPT_JSON);
    let text =
        std::fs::read_to_string(&jp).with_context(|| format!("{}: cannot read", jp.display()))?;
    let state: S = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: field `json`: {e}", jp.display()))?;
    let wp = dir.join(CKPT_WEIGHTS);
    let t = candle_core::safetensors::load(&wp, dev).map_err(|e| {
        anyhow::anyhow!(
            "{}: not a readable safetensors checkpoint: {e}",
            wp.display()
        )
    })?;
    Ok((state, t.into_iter().collect(), wp.display().to_string()))
}

/// The optimiser saved beside the weights (`adam.m.*`, `adam.v.*`).
pub fn restore_adam(t: &BTreeMap<String, Tensor>, s: &RunSettings, step: usize) -> AdamW {
    let mut opt = AdamW::new(s.lr, s.weight_decay);
    opt.step = step;
    for (k, v) in t {
        if let Some(n) = k.strip_prefix("adam.m.") {
            opt.m.insert(n.to_string(), v.clone());
        } else if let Some(n) = k.strip_prefix("adam.v.") {
            opt.v.insert(n.to_string(), v.clone());
        }
    }
    opt
}

/// Mean losses of a batch: language model (nats per target token) and
/// classification (summed over kinds, or None), plus class hits/totals.
pub fn losses(
    model: &Gpt,
    b: &Batch,
    train: bool,
) -> Result<(Tensor, Option<Tensor>, Vec<(usize, usize)>)> {
    let cfg = &model.cfg;
    let (logits, cls, _) =
        model.forward(&b.tokens, &b.pos_a, b.pos_b.as_ref(), &b.bias, None, train)?;
    let n = logits.dims3()?.0 * b.t;
    let lsm = candle_nn::ops::log_softmax(&logits.reshape((n, cfg.vocab_size))?, D::Minus1)?;
    let picked = lsm.gather(&b.targets.unsqueeze(1)?, 1)?.squeeze(1)?;
    let lm = ((picked * &b.weights)?.sum_all()? * (-1.0 / b.n_targets.max(1) as f64))?;
    let mut cls_loss: Option<Tensor> = None;
    let mut hits = Vec::new();
    for (c, (_, values)) in cfg.classes.iter().enumerate() {
        let Some((rows, idx)) = &b.classes[c] else {
            hits.push((0, 0));
            continue;
        };
        let x = cls[c].reshape((n, values.len()))?.index_select(rows, 0)?;
        let (l, h) = class_loss(&x, idx)?;
        hits.push(h);
        cls_loss = Some(match cls_loss {
            Some(a) => (a + l)?,
            None => l,
        });
    }
    Ok((lm, cls_loss, hits))
}

/// Mean cross-entropy of class logits `x: [rows, classes]` against `idx`,
/// and (hits, rows) of their argmax.
pub fn class_loss(x: &Tensor, idx: &Tensor) -> Result<(Tensor, (usize, usize))> {
    let pred = x.argmax(D::Minus1)?.to_vec1::<u32>()?;
    let truth = idx.to_vec1::<u32>()?;
    let hits = pred.iter().zip(&truth).filter(|(a, b)| a == b).count();
    let l = candle_nn::ops::log_softmax(x, D::Minus1)?
        .gather(&idx.unsqueeze(1)?, 1)?
        .mean_all()?
        .neg()?;
    Ok((l, (hits, truth.len())))
}

/// Held-out figures over fixed windows: mean loss per target token,
/// bits/frame and (for class heads) accuracy per kind.
pub const EVAL_WINDOWS: usize = 384;

pub struct Evaluation {
    pub loss: f64,
    pub bits_per_frame: f64,
    pub accuracy: Vec<(String, f64, usize)>,
}

pub fn evaluate(
    model: &Gpt,
    vocab: &Vocabulary,
    corpus: &Corpus,
    batch: usize,
    dev: &Device,
) -> Result<Evaluation> {
    evaluate_on(model, vocab, corpus, batch, dev, EVAL_WINDOWS)
}

/// [`evaluate`] on at most `max_windows` windows (spread evenly).
pub fn evaluate_on(
    model: &Gpt,
    vocab: &Vocabulary,
    corpus: &Corpus,
    batch: usize,
    dev: &Device,
    max_windows: usize,
) -> Result<Evaluation> {
    let cfg = &model.cfg;
    let fl = cfg.frame_len;
    let windows = data::spread(
        data::eval_windows(&corpus.val, fl, cfg.max_frames),
        max_windows,
    );
    if windows.is_empty() {
        bail!("no validation windows (the split held out nothing)");
    }
    let mut rng = StdRng::seed_from_u64(1234);
    let opts = ExampleOptions {
        keep_label: 1.0,
        classify: 0.0,
        mask_rate: 0.15,
    };
    let (mut sum, mut count) = (0f64, 0usize);
    let mut hits = vec![(0usize, 0usize); cfg.classes.len()];
    for chunk in windows.chunks(batch.max(1)) {
        for as_cls in [false, true] {
            if as_cls && cfg.classes.is_empty() {
                continue;
            }
            let exs: Vec<Example> = chunk
                .iter()
                .map(|(f, l)| data::example(cfg, vocab, f, l, as_cls, &opts, &mut rng))
                .collect();
            let b = data::batch(cfg, vocab, &exs, dev)?;
            let (lm, _, h) = losses(model, &b, false)?;
            if !as_cls {
                sum += lm.to_scalar::<f32>()? as f64 * b.n_targets as f64;
                count += b.n_targets;
            } else {
                for (acc, (a, n)) in hits.iter_mut().zip(h) {
                    acc.0 += a;
                    acc.1 += n;
                }
            }
        }
    }
    let loss = sum / count.max(1) as f64;
    Ok(Evaluation {
        loss,
        bits_per_frame: bits_per_frame(loss, fl),
        accuracy: cfg
            .classes
            .iter()
            .zip(hits)
            .map(|((k, _), (a, n))| (k.clone(), a as f64 / n.max(1) as f64, n))
            .collect(),
    })
}

/// Learning rate at `step`: linear warm-up, then cosine decay to
/// `min_lr_ratio · lr`.
pub fn lr_at(s: &RunSettings, step: usize) -> f64 {
    if step < s.warmup {
        return s.lr * (step + 1) as f64 / s.warmup as f64;
    }
    let p = (step - s.warmup) as f64 / (s.steps.saturating_sub(s.warmup)).max(1) as f64;
    let c = 0.5 * (1.0 + (std::f64::consts::PI * p.min(1.0)).cos());
    s.lr * (s.min_lr_ratio + (1.0 - s.min_lr_ratio) * c)
}

/// One optimisation step on a fresh batch; returns (lm loss, tokens).
pub fn train_step(
    model: &Gpt,
    opt: &mut AdamW,
    vocab: &Vocabulary,
    corpus: &Corpus,
    cum: &[usize],
    s: &RunSettings,
    rng: &mut StdRng,
    dev: &Device,
) -> Result<(f64, usize)> {
    let cfg = &model.cfg;
    let opts = ExampleOptions {
        keep_label: s.keep_label,
        classify: s.classify_fraction,
        mask_rate: s.mask_rate,
    };
    let mut exs = Vec::with_capacity(s.batch);
    for _ in 0..s.batch {
        let (f, l) = data::draw_window(&corpus.train, cum, cfg.frame_len, cfg.max_frames, rng);
        let as_cls = !cfg.classes.is_empty() && rng.gen::<f64>() < opts.classify;
        exs.push(data::example(cfg, vocab, f, l, as_cls, &opts, rng));
    }
    let tokens: usize = exs.iter().map(|e| e.tokens.len()).sum();
    let b = data::batch(cfg, vocab, &exs, dev)?;
    let (lm, cls, _) = losses(model, &b, true)?;
    let loss = lm.to_scalar::<f32>()? as f64;
    optimise(&model.params, opt, &lm, cls.as_ref(), s.class_weight, loss)?;
    Ok((loss, tokens))
}

/// One optimiser step on `lm` plus the weighted class loss; a non-finite
/// `reported` loss stops the run instead.
pub fn optimise(
    params: &model::Params,
    opt: &mut AdamW,
    lm: &Tensor,
    cls: Option<&Tensor>,
    class_weight: f64,
    reported: f64,
) -> Result<()> {
    if !reported.is_finite() {
        bail!(
            "training diverged: loss {reported} at step {} (lower --lr)",
            opt.step
        );
    }
    let total = match cls {
        Some(c) => (lm + (c * class_weight)?)?,
        None => lm.clone(),
    };
    let grads = total.backward()?;
    opt.step(params, &grads)?;
    Ok(())
}

pub fn device() -> Device {
    Device::Cpu
}
