//! Training the learned in-betweener ([`crate::lm::inbetween`]): a
//! bidirectional pre-LN transformer over windows of SLERP-interpolated
//! keyframes, regressing the residual to the real motion on in-between
//! frames. Keyframe spacing is drawn per example (so the model serves any
//! keyframe count); clips are split into training and held-out sets by a
//! hash of their names, per corpus, like the language model's data.

use super::export::{value_info, Builder, DataType, ONNX_FILE};
use super::model::{attention_probs, filled, insert_blocks, normal, AdamW, Params};
use crate::features::smpl24_at_60;
use crate::keyframes::metrics::mse;
use crate::lm::inbetween::{
    phases, poses, window_input, InbetweenConfig, InbetweenManifest, Inbetweener, FORMAT, KIND,
    POSE_DIM,
};
use crate::lm::manifest::{sha256_hex, DataInfo, MANIFEST_FILE};
use crate::motion::{Labels, Motion};
use anyhow::{bail, Result};
use candle_core::{DType, Device, Tensor};
use prost::Message;
use rand::rngs::StdRng;
use rand::Rng;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// The network: `in → +pos → blocks → ln_f → out`.
pub struct InbetweenNet {
    pub cfg: InbetweenConfig,
    pub params: Params,
}

impl InbetweenNet {
    pub fn new(cfg: InbetweenConfig, dev: &Device) -> candle_core::Result<InbetweenNet> {
        let (d, ff, l) = (cfg.d_model, cfg.d_ff, cfg.n_layers);
        let mut p = BTreeMap::new();
        p.insert("in.w".into(), normal(&[cfg.in_dim(), d], 0.02, dev)?);
        p.insert("in.b".into(), filled(&[d], 0.0, dev)?);
        p.insert("pos_emb".into(), normal(&[cfg.window, d], 0.02, dev)?);
        insert_blocks(&mut p, l, d, ff, dev)?;
        // A zero output layer: training starts from SLERP exactly.
        p.insert("out.w".into(), filled(&[d, POSE_DIM], 0.0, dev)?);
        p.insert("out.b".into(), filled(&[POSE_DIM], 0.0, dev)?);
        Ok(InbetweenNet {
            cfg,
            params: Params(p),
        })
    }

    fn lin(&self, x: &Tensor, pre: &str) -> candle_core::Result<Tensor> {
        self.params.lin(x, pre)
    }

    fn ln(&self, x: &Tensor, pre: &str) -> candle_core::Result<Tensor> {
        self.params.ln(x, pre, self.cfg.ln_eps)
    }

    /// `x`: `[B, window, in_dim]` → residual `[B, window, POSE_DIM]`.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let cfg = &self.cfg;
        let (b, t, _) = x.dims3()?;
        let (d, h, dh) = (cfg.d_model, cfg.n_heads, cfg.d_head());
        let mut x = self.lin(x, "in")?.broadcast_add(self.params.w("pos_emb"))?;
        let scale = 1.0 / (dh as f64).sqrt();
        for l in 0..cfg.n_layers {
            let n = |s: &str| format!("h{l}.{s}");
            let a = self.ln(&x, &n("ln1"))?;
            let heads = |w: &str| -> candle_core::Result<Tensor> {
                self.lin(&a, &n(w))?
                    .reshape((b, t, h, dh))?
                    .transpose(1, 2)?
                    .contiguous()
            };
            let (q, k, v) = (heads("q")?, heads("k")?, heads("v")?);
            let att = attention_probs(&q, &k, scale, None)?
                .matmul(&v)?
                .transpose(1, 2)?
                .contiguous()?
                .reshape((b, t, d))?;
            x = (x + self.lin(&att, &n("o"))?)?;
            let m = self.ln(&x, &n("ln2"))?;
            let m = self.lin(&m, &n("fc1"))?.apply(&super::fused::gelu_erf)?;
            x = (x + self.lin(&m, &n("fc2"))?)?;
        }
        self.lin(&self.ln(&x, "ln_f")?, "out")
    }

    /// Loads the weights of an exported in-betweener (its ONNX
    /// initialisers, by name); every parameter must be there with its shape.
    pub fn load_from_export(&self, model: &Inbetweener, dev: &Device) -> Result<()> {
        // Params::load_tensors checks names and shapes.
        let t = super::export::float_initializers(&model.onnx_path, dev)?;
        let file = model.onnx_path.display().to_string();
        self.params.load_tensors(&t, &file)
    }
}

/// The network as an ONNX graph: input `x [B, window, in_dim]`, output
/// `residual [B, window, POSE_DIM]`.
pub fn onnx_model(net: &InbetweenNet) -> Result<tract_onnx::pb::ModelProto> {
    let cfg = &net.cfg;
    let mut g = Builder::default();
    g.weights(net.params.tensors())?;
    let (d, h, dh) = (cfg.d_model as i64, cfg.n_heads as i64, cfg.d_head() as i64);
    let eps = cfg.ln_eps as f32;
    let x = g.lin("x", "in");
    let mut x = g.op("Add", &[&x, "pos_emb"], vec![], None);
    for l in 0..cfg.n_layers {
        let n = |s: &str| format!("h{l}.{s}");
        let (q, k, v) = g.qkv(&x, &n, eps, h, dh);
        let att = g.attend(&q, &k, &v, None, d, dh);
        let o = g.lin(&att, &n("o"));
        x = g.op("Add", &[&x, &o], vec![], None);
        x = g.mlp_residual(&x, &n, eps);
    }
    let xf = g.ln(&x, "ln_f", eps);
    let m = g.op("MatMul", &[&xf, "out.w"], vec![], None);
    g.op("Add", &[&m, "out.b"], vec![], Some("residual"));
    let w = cfg.window.to_string();
    Ok(g.model(
        "choreo_inbetweener",
        vec![value_info(
            "x",
            DataType::Float,
            &["B", &w, &cfg.in_dim().to_string()],
        )],
        vec![value_info(
            "residual",
            DataType::Float,
            &["B", &w, &POSE_DIM.to_string()],
        )],
    ))
}

/// Writes `dir/model.onnx` and `dir/manifest.json`.
pub fn export(
    net: &InbetweenNet,
    data: DataInfo,
    metrics: BTreeMap<String, f64>,
    training: serde_json::Value,
    dir: &Path,
) -> Result<InbetweenManifest> {
    std::fs::create_dir_all(dir)?;
    let bytes = onnx_model(net)?.encode_to_vec();
    std::fs::write(dir.join(ONNX_FILE), &bytes)?;
    let m = InbetweenManifest {
        format: FORMAT,
        kind: KIND.into(),
        config: net.cfg.clone(),
        onnx: ONNX_FILE.into(),
        onnx_sha256: sha256_hex(&bytes),
        data,
        metrics,
        training,
    };
    write_manifest(&m, dir)?;
    Ok(m)
}

/// Writes `dir/manifest.json` (after `metrics` were filled in; the ONNX
/// file and its hash are unchanged).
pub fn write_manifest(m: &InbetweenManifest, dir: &Path) -> Result<()> {
    let text = serde_json::to_string_pretty(m)? + "\n";
    std::fs::write(dir.join(MANIFEST_FILE), text)?;
    Ok(())
}

/// A clip prepared for training: SMPL-24 at 60 fps and its poses.
pub struct Clip {
    pub corpus: String,
    pub name: String,
    pub labels: Labels,
    pub motion: Motion,
}

/// Brings motions to SMPL-24 at 60 fps and splits them per corpus by a
/// hash of the name (`val_fraction` held out, at least one when a corpus
/// has two clips or more). Clips shorter than `min_frames` are dropped.
/// With `mirror`, every training clip also gets its left/right mirror.
pub fn prepare(
    motions: Vec<(String, Motion)>,
    val_fraction: f64,
    min_frames: usize,
    mirror: bool,
) -> Result<(Vec<Clip>, Vec<Clip>)> {
    let mut by: BTreeMap<String, Vec<Motion>> = BTreeMap::new();
    for (c, m) in motions {
        by.entry(c).or_default().push(m);
    }
    let (mut train, mut val) = (Vec::new(), Vec::new());
    for (corpus, mut list) in by {
        list.sort_by_key(|m| crate::data::split_hash(&m.name));
        let n_val = super::data::held_out_count(list.len(), val_fraction);
        for (i, m) in list.into_iter().enumerate() {
            let s = match smpl24_at_60(&m) {
                Ok(s) if s.frames() >= min_frames => s,
                Ok(_) => continue,
                Err(e) => {
                    tracing::warn!("skipping {}: {e}", m.name);
                    continue;
                }
            };
            let c = Clip {
                corpus: corpus.clone(),
                name: m.name.clone(),
                labels: m.labels.clone(),
                motion: s,
            };
            if i < n_val {
                val.push(c)
            } else {
                if mirror {
                    match c.motion.mirror() {
                        Ok(mm) => train.push(Clip {
                            corpus: c.corpus.clone(),
                            name: format!("{} (mirrored)", c.name),
                            labels: c.labels.clone(),
                            motion: mm,
                        }),
                        Err(e) => tracing::warn!("no mirror for {}: {e}", c.name),
                    }
                }
                train.push(c)
            }
        }
    }
    if train.is_empty() {
        bail!("empty corpus: no training clip of at least {min_frames} frames");
    }
    Ok((train, val))
}

/// One example: the input window and the residual target with its mask.
pub struct Example {
    pub x: Vec<f32>,
    pub target: Vec<f32>,
    pub mask: Vec<f32>,
}

/// Evenly spaced keyframes every `spacing` frames from `offset`, plus the
/// first and last frames.
pub fn spaced_keys(frames: usize, spacing: usize, offset: usize) -> Vec<usize> {
    let mut k = vec![0];
    let mut t = offset.max(1);
    while t < frames - 1 {
        k.push(t);
        t += spacing.max(1);
    }
    k.push(frames - 1);
    k.dedup();
    k
}

/// A random window of a clip, keyframes every `spacing` frames.
pub fn example(
    cfg: &InbetweenConfig,
    clip: &Clip,
    spacing: usize,
    rng: &mut StdRng,
) -> Result<Example> {
    let m = &clip.motion;
    let n = m.frames();
    let w0 = rng.gen_range(0..=n.saturating_sub(cfg.window));
    // A margin of two segments on each side, so the window's edges are
    // interpolated from keyframes outside it (and a spline's tangents from
    // their neighbours), as in a whole clip.
    let a = w0.saturating_sub(2 * spacing);
    let b = (w0 + cfg.window + 2 * spacing).min(n);
    let cut = m.cut(a, b)?;
    let keys = spaced_keys(cut.frames(), spacing, rng.gen_range(1..=spacing));
    let base = cfg.base.rebuild(&cut, &keys)?;
    let (orig, bp) = (poses(&cut)?, poses(&base)?);
    let phase = phases(&keys, cut.frames());
    let cond = cfg.condition_vector(&clip.labels);
    let start = w0 - a;
    let x = window_input(cfg, &bp, &phase, &cond, start);
    let inb = crate::lm::inbetween::inbetween_mask(&keys, cut.frames());
    let mut target = vec![0f32; cfg.window * POSE_DIM];
    let mut mask = vec![0f32; cfg.window];
    for i in 0..cfg.window {
        let t = start + i;
        if t >= cut.frames() || !inb[t] {
            continue;
        }
        mask[i] = 1.0;
        for k in 0..POSE_DIM {
            target[i * POSE_DIM + k] = (orig[t][k] - bp[t][k]) as f32;
        }
    }
    Ok(Example { x, target, mask })
}

/// Per-number weights of the pose for the loss, mean 1.
///
/// `Uniform` weighs every 6D number and the root translation alike.
/// `Fk` follows the evaluation's measure, the mean squared error of the
/// FK joint positions: to first order a small rotation error at joint j
/// moves every joint below it by its angle times that joint's rest
/// distance from j, so j's six numbers weigh the mean over the 24 joints
/// of the squared rest distances of j's descendants; the root translation
/// moves all 24 joints (weight 1 m² per number before the mean is made 1).
/// Leaf rotations (feet, head, hands) move no SMPL-24 joint and keep a
/// floor of 2 % of the mean, so they are still learned.
pub fn pose_weights(kind: LossWeights) -> Vec<f32> {
    if kind == LossWeights::Uniform {
        return vec![1.0; POSE_DIM];
    }
    let sk = crate::motion::Skeleton::smpl24();
    let rest = Motion::rest_positions(&sk);
    let n = sk.len();
    let mut w = vec![0f64; POSE_DIM];
    for j in 0..n {
        let mut acc = 0.0;
        for k in 0..n {
            let mut a = sk.parents[k];
            while let Some(p) = a {
                if p == j {
                    let d: f64 = (0..3).map(|c| (rest[k][c] - rest[j][c]).powi(2)).sum();
                    acc += d;
                    break;
                }
                a = sk.parents[p];
            }
        }
        for v in &mut w[j * 6..j * 6 + 6] {
            *v = acc / n as f64;
        }
    }
    for v in &mut w[n * 6..] {
        *v = 1.0;
    }
    let mean = w.iter().sum::<f64>() / POSE_DIM as f64;
    let floor = 0.02 * mean;
    let w: Vec<f64> = w.iter().map(|&v| v.max(floor)).collect();
    let mean = w.iter().sum::<f64>() / POSE_DIM as f64;
    w.iter().map(|&v| (v / mean) as f32).collect()
}

/// How the loss weighs the pose's numbers (see [`pose_weights`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum LossWeights {
    Uniform,
    Fk,
}

/// Weighted mean squared residual error over the in-between frames of a
/// batch (`weights`: [`POSE_DIM`] numbers, see [`pose_weights`]).
pub fn loss(
    net: &InbetweenNet,
    exs: &[Example],
    weights: &[f32],
    dev: &Device,
) -> candle_core::Result<Tensor> {
    let cfg = &net.cfg;
    let b = exs.len();
    let cat = |f: &dyn Fn(&Example) -> &Vec<f32>| -> Vec<f32> {
        exs.iter().flat_map(|e| f(e).iter().copied()).collect()
    };
    let x = Tensor::from_vec(cat(&|e| &e.x), (b, cfg.window, cfg.in_dim()), dev)?;
    let y = Tensor::from_vec(cat(&|e| &e.target), (b, cfg.window, POSE_DIM), dev)?;
    let m = Tensor::from_vec(cat(&|e| &e.mask), (b, cfg.window, 1), dev)?;
    let w = Tensor::from_slice(weights, (1, 1, POSE_DIM), dev)?;
    let count: f32 = exs.iter().map(|e| e.mask.iter().sum::<f32>()).sum();
    let err = (net.forward(&x)? - y)?
        .sqr()?
        .broadcast_mul(&m)?
        .broadcast_mul(&w)?;
    err.sum_all()? / (count.max(1.0) as f64 * POSE_DIM as f64)
}

/// Settings of a training run.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    pub steps: usize,
    pub batch: usize,
    pub lr: f64,
    pub warmup: usize,
    pub weight_decay: f64,
    /// Keyframe spacing drawn uniformly from this range (frames at 60 fps).
    pub spacing: (usize, usize),
    pub seed: u64,
    pub max_seconds: Option<f64>,
    /// Draw this fraction of each batch from one corpus (e.g. 0.25 of
    /// `aistpp`), the rest by length from all clips.
    pub corpus_share: Option<(String, f64)>,
    /// How the loss weighs the pose's numbers.
    pub loss_weights: LossWeights,
}

/// Train; `log(step, loss, lr)` is called every `every` steps.
pub fn train(
    net: &InbetweenNet,
    clips: &[Clip],
    s: &Settings,
    rng: &mut StdRng,
    dev: &Device,
    log: &mut dyn FnMut(usize, f64, f64),
) -> Result<usize> {
    let mut opt = AdamW::new(s.lr, s.weight_decay);
    // Clips drawn in proportion to their length.
    let mut cum = Vec::with_capacity(clips.len());
    let mut acc = 0;
    for c in clips {
        acc += c.motion.frames();
        cum.push(acc);
    }
    let favoured: Vec<&Clip> = match &s.corpus_share {
        Some((corpus, _)) => clips.iter().filter(|c| &c.corpus == corpus).collect(),
        None => Vec::new(),
    };
    let weights = pose_weights(s.loss_weights);
    let t0 = std::time::Instant::now();
    let mut done = 0;
    for step in 0..s.steps {
        if s.max_seconds
            .is_some_and(|m| t0.elapsed().as_secs_f64() > m)
        {
            break;
        }
        let lr = if step < s.warmup {
            s.lr * (step + 1) as f64 / s.warmup as f64
        } else {
            let p = (step - s.warmup) as f64 / (s.steps - s.warmup).max(1) as f64;
            s.lr * (0.1 + 0.9 * 0.5 * (1.0 + (std::f64::consts::PI * p).cos()))
        };
        opt.lr = lr;
        let mut exs = Vec::with_capacity(s.batch);
        while exs.len() < s.batch {
            let c = match &s.corpus_share {
                Some((_, share)) if !favoured.is_empty() && rng.gen::<f64>() < *share => {
                    favoured[rng.gen_range(0..favoured.len())]
                }
                _ => {
                    let r = rng.gen_range(0..acc);
                    &clips[cum.partition_point(|&x| x <= r)]
                }
            };
            let spacing = rng.gen_range(s.spacing.0..=s.spacing.1);
            exs.push(example(&net.cfg, c, spacing, rng)?);
        }
        let l = loss(net, &exs, &weights, dev)?;
        let v = l.to_scalar::<f32>()? as f64;
        if !v.is_finite() {
            bail!("training diverged at step {step} (loss {v}); lower --lr");
        }
        let grads = l.backward()?;
        opt.step(&net.params, &grads)?;
        log(step, v, lr);
        done = step + 1;
    }
    Ok(done)
}

/// One row of the held-out comparison.
#[derive(Clone, Debug, Serialize)]
pub struct EvalRow {
    pub spacing: usize,
    pub clips: usize,
    pub frames: usize,
    /// Eq. 2.8 on FK joint positions, cm², mean over clips.
    pub slerp_cm2: f64,
    /// Least-squares Bézier fitted to the clip's own in-betweens (sees the
    /// ground truth: a bound, not a competitor).
    pub bezier_fit_cm2: f64,
    /// Bézier with control-point offsets averaged over training clips at
    /// the same spacing (the thesis's fair Bézier).
    pub bezier_avg_cm2: f64,
    /// Catmull-Rom through the keyframes (no in-between seen).
    pub catmull_rom_cm2: f64,
    pub learned_cm2: f64,
}

/// Held-out MSE (cm², FK positions) of SLERP, Bézier (fitted to the clip,
/// and averaged over `train`), Catmull-Rom and the exported model on whole clips with
/// keyframes every `spacing` frames.
pub fn evaluate(
    model: &Inbetweener,
    train: &[Clip],
    clips: &[Clip],
    spacings: &[usize],
) -> Result<Vec<EvalRow>> {
    use crate::keyframes::inbetween::{bezier, catmull_rom, slerp, BezierOffsets};
    let mut rows = Vec::new();
    for &s in spacings {
        let fit_on: Vec<(&Motion, Vec<usize>)> = train
            .iter()
            .filter(|c| c.motion.frames() >= 2 * s)
            .take(200)
            .map(|c| (&c.motion, spaced_keys(c.motion.frames(), s, s)))
            .collect();
        let avg = BezierOffsets::fit(&fit_on)?;
        let mut sums = [0.0f64; 5];
        let (mut n, mut frames) = (0, 0);
        for c in clips {
            let m = &c.motion;
            if m.frames() < 2 * s {
                continue;
            }
            let keys = spaced_keys(m.frames(), s, s);
            let p = m.positions();
            let cm2 = |r: &Motion| mse(&p, &r.positions()) * 1e4;
            sums[0] += cm2(&slerp(m, &keys)?);
            sums[1] += cm2(&bezier(m, &keys)?);
            sums[2] += cm2(&avg.apply(m, &keys)?);
            sums[3] += cm2(&model.rebuild(m, &keys)?);
            sums[4] += cm2(&catmull_rom(m, &keys)?);
            n += 1;
            frames += m.frames();
        }
        let k = n.max(1) as f64;
        rows.push(EvalRow {
            spacing: s,
            clips: n,
            frames,
            slerp_cm2: sums[0] / k,
            bezier_fit_cm2: sums[1] / k,
            bezier_avg_cm2: sums[2] / k,
            catmull_rom_cm2: sums[4] / k,
            learned_cm2: sums[3] / k,
        });
    }
    Ok(rows)
}

/// Largest |candle − tract| over a random window.
pub fn parity(net: &InbetweenNet, model: &Inbetweener, rng: &mut StdRng) -> Result<f64> {
    let cfg = &net.cfg;
    let x: Vec<f32> = (0..cfg.window * cfg.in_dim())
        .map(|_| rng.gen_range(-1.0f32..1.0))
        .collect();
    let want = net
        .forward(&Tensor::from_vec(
            x.clone(),
            (1, cfg.window, cfg.in_dim()),
            &Device::Cpu,
        )?)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let got = model.run_window(&x)?;
    Ok(want
        .iter()
        .zip(&got)
        .map(|(a, b)| (a - b).abs() as f64)
        .fold(0.0, f64::max))
}

/// Zero-initialised output makes a fresh model's parity trivial; this
/// perturbs every parameter so the parity test means something.
pub fn jitter(net: &InbetweenNet, rng: &mut StdRng) -> Result<()> {
    for v in net.params.values() {
        let n = v.elem_count();
        let noise: Vec<f32> = (0..n).map(|_| rng.gen_range(-0.05f32..0.05)).collect();
        let t = (v.as_tensor() + Tensor::from_vec(noise, v.dims(), &Device::Cpu)?)?;
        v.set(&t.to_dtype(DType::F32)?)?;
    }
    Ok(())
}
