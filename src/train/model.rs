//! The GPT in candle: pre-LayerNorm blocks, GELU (erf form), learned
//! positions (absolute or frame + slot), a language-model head and one
//! linear class head per label kind. Built from tensor operations with
//! gradients (LayerNorm, softmax and GELU as one-pass kernels,
//! [`super::fused`]), each with a one-to-one ONNX twin in `export.rs`.

use crate::lm::ModelConfig;
use candle_core::{DType, Device, Result, Tensor, Var};
use std::collections::BTreeMap;

/// LayerNorm over the last axis.
pub fn layer_norm(x: &Tensor, w: &Tensor, b: &Tensor, eps: f64) -> Result<Tensor> {
    super::fused::layer_norm(x, w, b, eps)
}

/// `x · w + b`.
pub fn linear(x: &Tensor, w: &Tensor, b: &Tensor) -> Result<Tensor> {
    x.broadcast_matmul(w)?.broadcast_add(b)
}

/// Softmax over keys of `q · kᵀ · scale (+ bias)`; `q`, `k`: `[B, H, T, dh]`.
pub fn attention_probs(
    q: &Tensor,
    k: &Tensor,
    scale: f64,
    bias: Option<&Tensor>,
) -> Result<Tensor> {
    let mut scores = (q.matmul(&k.transpose(2, 3)?.contiguous()?)? * scale)?;
    if let Some(b) = bias {
        scores = scores.broadcast_add(b)?;
    }
    super::fused::softmax_last_dim(&scores)
}

pub(crate) fn normal(shape: &[usize], std: f64, dev: &Device) -> Result<Var> {
    Var::from_tensor(&Tensor::randn(0f32, std as f32, shape, dev)?)
}
pub(crate) fn filled(shape: &[usize], v: f32, dev: &Device) -> Result<Var> {
    Var::from_tensor(&(Tensor::ones(shape, DType::F32, dev)? * v as f64)?)
}

/// The parameters of `layers` pre-LN blocks (`h{l}.ln1/q/k/v/o/ln2/fc1/fc2`)
/// and the final `ln_f`: N(0, 0.02) weights, residual projections scaled
/// by 1/√(2·layers), zero biases, unit norms.
pub fn insert_blocks(
    p: &mut BTreeMap<String, Var>,
    layers: usize,
    d: usize,
    ff: usize,
    dev: &Device,
) -> Result<()> {
    insert_stack(p, "h", layers, d, ff, dev)?;
    p.insert("ln_f.w".into(), filled(&[d], 1.0, dev)?);
    p.insert("ln_f.b".into(), filled(&[d], 0.0, dev)?);
    Ok(())
}

/// `layers` pre-LN blocks named `{pre}{l}.ln1/q/k/v/o/ln2/fc1/fc2`, with
/// the initialisation of [`insert_blocks`] (no final norm).
pub fn insert_stack(
    p: &mut BTreeMap<String, Var>,
    pre: &str,
    layers: usize,
    d: usize,
    ff: usize,
    dev: &Device,
) -> Result<()> {
    let resid = 0.02 / (2.0 * layers as f64).sqrt();
    for l in 0..layers {
        let n = |s: &str| format!("{pre}{l}.{s}");
        p.insert(n("ln1.w"), filled(&[d], 1.0, dev)?);
        p.insert(n("ln1.b"), filled(&[d], 0.0, dev)?);
        for w in ["q", "k", "v"] {
            p.insert(n(&format!("{w}.w")), normal(&[d, d], 0.02, dev)?);
            p.insert(n(&format!("{w}.b")), filled(&[d], 0.0, dev)?);
        }
        p.insert(n("o.w"), normal(&[d, d], resid, dev)?);
        p.insert(n("o.b"), filled(&[d], 0.0, dev)?);
        p.insert(n("ln2.w"), filled(&[d], 1.0, dev)?);
        p.insert(n("ln2.b"), filled(&[d], 0.0, dev)?);
        p.insert(n("fc1.w"), normal(&[d, ff], 0.02, dev)?);
        p.insert(n("fc1.b"), filled(&[ff], 0.0, dev)?);
        p.insert(n("fc2.w"), normal(&[ff, d], resid, dev)?);
        p.insert(n("fc2.b"), filled(&[d], 0.0, dev)?);
    }
    Ok(())
}

/// Named parameters (the names the exporter and checkpoints use), with the
/// lookups both networks make.
#[derive(Default)]
pub struct Params(pub BTreeMap<String, Var>);

impl std::ops::Deref for Params {
    type Target = BTreeMap<String, Var>;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl Params {
    pub fn w(&self, name: &str) -> &Tensor {
        self.0
            .get(name)
            .unwrap_or_else(|| panic!("parameter {name} exists"))
            .as_tensor()
    }

    /// `x · pre.w + pre.b`.
    pub fn lin(&self, x: &Tensor, pre: &str) -> Result<Tensor> {
        linear(x, self.w(&format!("{pre}.w")), self.w(&format!("{pre}.b")))
    }

    /// LayerNorm with `pre.w`, `pre.b`.
    pub fn ln(&self, x: &Tensor, pre: &str, eps: f64) -> Result<Tensor> {
        layer_norm(
            x,
            self.w(&format!("{pre}.w")),
            self.w(&format!("{pre}.b")),
            eps,
        )
    }

    /// One pre-LN block `pre.{ln1,q,k,v,o,ln2,fc1,fc2}` on `x: [B, T, d]`
    /// with `heads` heads and an additive attention `bias` (broadcastable
    /// to `[B, H, T, T]`), no dropout.
    pub fn block(
        &self,
        x: &Tensor,
        pre: &str,
        heads: usize,
        eps: f64,
        bias: Option<&Tensor>,
    ) -> Result<Tensor> {
        let (b, t, d) = x.dims3()?;
        let dh = d / heads;
        let n = |s: &str| format!("{pre}.{s}");
        let a = self.ln(x, &n("ln1"), eps)?;
        let split = |w: &str| -> Result<Tensor> {
            self.lin(&a, &n(w))?
                .reshape((b, t, heads, dh))?
                .transpose(1, 2)?
                .contiguous()
        };
        let (q, k, v) = (split("q")?, split("k")?, split("v")?);
        let att = attention_probs(&q, &k, 1.0 / (dh as f64).sqrt(), bias)?
            .matmul(&v)?
            .transpose(1, 2)?
            .contiguous()?
            .reshape((b, t, d))?;
        let x = (x + self.lin(&att, &n("o"))?)?;
        let m = self.ln(&x, &n("ln2"), eps)?;
        let m = self.lin(&m, &n("fc1"))?.apply(&super::fused::gelu_erf)?;
        x + self.lin(&m, &n("fc2"))?
    }

    /// How many numbers.
    pub fn count(&self) -> usize {
        self.0.values().map(|v| v.elem_count()).sum()
    }

    /// As named tensors (for checkpoints and export).
    pub fn tensors(&self) -> BTreeMap<String, Tensor> {
        self.0
            .iter()
            .map(|(k, v)| (k.clone(), v.as_tensor().clone()))
            .collect()
    }

    /// Like `load_tensors`, but a parameter the checkpoint lacks keeps its
    /// current value (a warm start into a larger configuration); returns
    /// those names. A shape mismatch is still an error.
    pub fn load_matching(
        &self,
        t: &BTreeMap<String, Tensor>,
        file: &str,
    ) -> anyhow::Result<Vec<String>> {
        self.load(t, file, true)
    }

    /// Sets to zero the residual projections (`*.o.w`, `*.fc2.w`) of the
    /// blocks every one of whose parameters is among `fresh` (those a warm
    /// start did not find in its parent): such a block then adds nothing,
    /// so a model grown by blocks computes exactly what its parent did
    /// until training moves them. Returns the blocks zeroed.
    pub fn zero_fresh_blocks(&self, fresh: &[String]) -> Result<Vec<String>> {
        let fresh: std::collections::BTreeSet<&str> = fresh.iter().map(|s| s.as_str()).collect();
        let mut blocks = Vec::new();
        for name in &fresh {
            let Some(block) = name.strip_suffix(".o.w") else {
                continue;
            };
            let prefix = format!("{block}.");
            let whole = self
                .0
                .keys()
                .filter(|k| k.starts_with(&prefix))
                .all(|k| fresh.contains(k.as_str()));
            if !whole {
                continue;
            }
            for p in ["o.w", "fc2.w"] {
                let v = &self.0[&format!("{prefix}{p}")];
                v.set(&v.as_tensor().zeros_like()?)?;
            }
            blocks.push(block.to_string());
        }
        Ok(blocks)
    }

    /// Replaces every parameter from named tensors, which must all be there
    /// with their shapes; errors name `file` and the field.
    pub fn load_tensors(&self, t: &BTreeMap<String, Tensor>, file: &str) -> anyhow::Result<()> {
        self.load(t, file, false).map(|_| ())
    }

    fn load(
        &self,
        t: &BTreeMap<String, Tensor>,
        file: &str,
        allow_missing: bool,
    ) -> anyhow::Result<Vec<String>> {
        let mut missing = Vec::new();
        for (name, var) in &self.0 {
            let Some(src) = t.get(name) else {
                if allow_missing {
                    missing.push(name.clone());
                    continue;
                }
                anyhow::bail!("{file}: field `{name}`: missing");
            };
            if src.dims() != var.dims() {
                anyhow::bail!(
                    "{file}: field `{name}`: shape {:?}, the configuration wants {:?}",
                    src.dims(),
                    var.dims()
                );
            }
            var.set(&src.to_dtype(DType::F32)?)?;
        }
        Ok(missing)
    }
}

/// The GPT: its configuration, parameters and dropout.
pub struct Gpt {
    pub cfg: ModelConfig,
    pub params: Params,
    pub dropout: f32,
}

/// One layer's keys and values, `[B, H, S, dh]`.
pub type KvPair = (Tensor, Tensor);

impl Gpt {
    /// A freshly initialised model (N(0, 0.02) weights, residual
    /// projections scaled by 1/√(2·layers), zero biases, unit norms).
    pub fn new(cfg: ModelConfig, dropout: f32, dev: &Device) -> Result<Gpt> {
        let (d, v, ff) = (cfg.d_model, cfg.vocab_size, cfg.d_ff);
        let mut p = BTreeMap::new();
        p.insert("tok_emb".into(), normal(&[v, d], 0.02, dev)?);
        p.insert("pos_a".into(), normal(&[cfg.table_a(), d], 0.02, dev)?);
        if cfg.table_b() > 0 {
            p.insert("pos_b".into(), normal(&[cfg.table_b(), d], 0.02, dev)?);
        }
        insert_blocks(&mut p, cfg.n_layers, d, ff, dev)?;
        p.insert("head.w".into(), normal(&[d, v], 0.02, dev)?);
        p.insert("head.b".into(), filled(&[v], 0.0, dev)?);
        for (k, values) in &cfg.classes {
            p.insert(format!("cls.{k}.w"), normal(&[d, values.len()], 0.02, dev)?);
            p.insert(format!("cls.{k}.b"), filled(&[values.len()], 0.0, dev)?);
        }
        Ok(Gpt {
            cfg,
            params: Params(p),
            dropout,
        })
    }

    fn drop(&self, x: Tensor, train: bool) -> Result<Tensor> {
        if train && self.dropout > 0.0 {
            candle_nn::ops::dropout(&x, self.dropout)
        } else {
            Ok(x)
        }
    }

    /// The forward pass. `tokens`, `pos_a`, `pos_b`: `[B, T]` u32; `bias`:
    /// additive attention bias broadcastable to `[B, H, T, S]` (S = past +
    /// T); `past`: one (K, V) per layer or none. Returns logits
    /// `[B, T, V]`, class logits per kind `[B, T, C]` and the extended
    /// keys/values.
    pub fn forward(
        &self,
        tokens: &Tensor,
        pos_a: &Tensor,
        pos_b: Option<&Tensor>,
        bias: &Tensor,
        past: Option<&[KvPair]>,
        train: bool,
    ) -> Result<(Tensor, Vec<Tensor>, Vec<KvPair>)> {
        let cfg = &self.cfg;
        let (b, t) = tokens.dims2()?;
        let (d, h, dh) = (cfg.d_model, cfg.n_heads, cfg.d_head());
        let emb = |table: &str, ids: &Tensor| -> Result<Tensor> {
            self.params
                .w(table)
                .index_select(&ids.flatten_all()?, 0)?
                .reshape((b, t, d))
        };
        let mut x = (emb("tok_emb", tokens)? + emb("pos_a", pos_a)?)?;
        if let Some(pb) = pos_b {
            x = (x + emb("pos_b", pb)?)?;
        }
        x = self.drop(x, train)?;
        let scale = 1.0 / (dh as f64).sqrt();
        let mut present = Vec::with_capacity(cfg.n_layers);
        for l in 0..cfg.n_layers {
            let n = |s: &str| format!("h{l}.{s}");
            let a = self.params.ln(&x, &n("ln1"), self.cfg.ln_eps)?;
            let heads = |w: &str| -> Result<Tensor> {
                self.params
                    .lin(&a, &n(w))?
                    .reshape((b, t, h, dh))?
                    .transpose(1, 2)?
                    .contiguous()
            };
            let (q, mut k, mut v) = (heads("q")?, heads("k")?, heads("v")?);
            if let Some(p) = past {
                k = Tensor::cat(&[&p[l].0, &k], 2)?;
                v = Tensor::cat(&[&p[l].1, &v], 2)?;
            }
            let probs = self.drop(attention_probs(&q, &k, scale, Some(bias))?, train)?;
            let att = probs
                .matmul(&v)?
                .transpose(1, 2)?
                .contiguous()?
                .reshape((b, t, d))?;
            let att = self.drop(self.params.lin(&att, &n("o"))?, train)?;
            x = (x + att)?;
            let m = self.params.ln(&x, &n("ln2"), self.cfg.ln_eps)?;
            let m = self
                .params
                .lin(&m, &n("fc1"))?
                .apply(&super::fused::gelu_erf)?;
            let m = self.drop(self.params.lin(&m, &n("fc2"))?, train)?;
            x = (x + m)?;
            present.push((k, v));
        }
        let x = self.params.ln(&x, "ln_f", self.cfg.ln_eps)?;
        let logits = self.params.lin(&x, "head")?;
        let cls = cfg
            .classes
            .iter()
            .map(|(k, _)| self.params.lin(&x, &format!("cls.{k}")))
            .collect::<Result<Vec<_>>>()?;
        Ok((logits, cls, present))
    }
}

/// AdamW with decoupled weight decay on matrices, bias-corrected moments,
/// and global-norm gradient clipping. Its state is checkpointed.
pub struct AdamW {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    pub weight_decay: f64,
    pub clip: f64,
    pub step: usize,
    pub m: BTreeMap<String, Tensor>,
    pub v: BTreeMap<String, Tensor>,
}

impl AdamW {
    pub fn new(lr: f64, weight_decay: f64) -> AdamW {
        AdamW {
            lr,
            beta1: 0.9,
            beta2: 0.95,
            eps: 1e-8,
            weight_decay,
            clip: 1.0,
            step: 0,
            m: BTreeMap::new(),
            v: BTreeMap::new(),
        }
    }

    /// One update; returns the gradient norm before clipping.
    pub fn step(
        &mut self,
        params: &BTreeMap<String, Var>,
        grads: &candle_core::backprop::GradStore,
    ) -> Result<f64> {
        let mut sq = 0f64;
        let mut gs = Vec::new();
        for (name, var) in params {
            if let Some(g) = grads.get(var.as_tensor()) {
                sq += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
                // Detached: a gradient keeps its step's graph alive otherwise.
                gs.push((name, var, g.detach()));
            }
        }
        let norm = sq.sqrt();
        let factor = if norm > self.clip {
            self.clip / norm
        } else {
            1.0
        };
        self.step += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.step as i32);
        let c2 = 1.0 - b2.powi(self.step as i32);
        for (name, var, g) in gs {
            let g = (g * factor)?;
            let m = match self.m.get(name) {
                Some(m) => ((m * b1)? + (&g * (1.0 - b1))?)?,
                None => (&g * (1.0 - b1))?,
            };
            let v = match self.v.get(name) {
                Some(v) => ((v * b2)? + (g.sqr()? * (1.0 - b2))?)?,
                None => (g.sqr()? * (1.0 - b2))?,
            };
            let upd = ((&m / c1)? / ((&v / c2)?.sqrt()? + self.eps)?)?;
            let w = var.as_tensor();
            // Weight matrices only: embedding and position tables (names
            // without `.w`) are not decayed.
            let decay = var.rank() == 2 && name.ends_with(".w");
            let mut next = (w - (upd * self.lr)?)?;
            if decay && self.weight_decay > 0.0 {
                next = (next - (w * (self.lr * self.weight_decay))?)?;
            }
            var.set(&next.detach())?;
            self.m.insert(name.clone(), m.detach());
            self.v.insert(name.clone(), v.detach());
        }
        Ok(norm)
    }
}
