//! The exported model in tract: one forward step over new tokens, with the
//! past keys and values as inputs and the extended ones as outputs, so a
//! stream costs one step per token rather than one window. Every tract type
//! stays inside this module.

use super::{LmError, Manifest, ModelConfig, Objective, Pos, PosScheme};
use std::path::Path;
use std::sync::Arc;
use tract_onnx::prelude::*;

type Plan = Arc<TypedRunnableModel>;

/// Past keys and values, one pair per layer, each `[1, heads, len, d_head]`.
pub struct Kv {
    layers: Vec<(Tensor, Tensor)>,
    len: usize,
}

impl Kv {
    pub fn empty(cfg: &ModelConfig) -> Kv {
        let shape = [1, cfg.n_heads, 0, cfg.d_head()];
        let z = || Tensor::zero::<f32>(&shape).expect("empty tensor");
        Kv {
            layers: (0..cfg.n_layers).map(|_| (z(), z())).collect(),
            len: 0,
        }
    }
    /// Positions already cached.
    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// What one step returns for its new tokens.
pub struct StepOut {
    /// `[tokens × vocab]` row-major.
    pub logits: Vec<f32>,
    /// Per class kind (manifest order): `[tokens × classes]` row-major.
    pub class_logits: Vec<Vec<f32>>,
}

/// A loaded, optimised model: immutable and shared between requests.
pub struct LmSession {
    pub manifest: Manifest,
    plan: Plan,
}

/// The graph's input names for a configuration (the trainer's exporter
/// writes them in this order).
pub fn input_names(cfg: &ModelConfig) -> Vec<String> {
    let mut v = vec!["tokens".to_string(), "pos_a_ids".into()];
    if cfg.positions == PosScheme::FrameSlot {
        v.push("pos_b_ids".into());
    }
    v.push("attn_bias".into());
    for l in 0..cfg.n_layers {
        v.push(format!("past_k_{l}"));
        v.push(format!("past_v_{l}"));
    }
    v
}

/// The graph's output names for a configuration.
pub fn output_names(cfg: &ModelConfig) -> Vec<String> {
    let mut v = vec!["logits".to_string()];
    for (k, _) in &cfg.classes {
        v.push(format!("cls_{k}"));
    }
    for l in 0..cfg.n_layers {
        v.push(format!("present_k_{l}"));
        v.push(format!("present_v_{l}"));
    }
    v
}

fn rt(e: impl std::fmt::Display) -> LmError {
    LmError::Runtime(e.to_string())
}

impl LmSession {
    /// Loads a model folder (or its manifest), checking the manifest
    /// against the ONNX file and the graph's inputs and outputs against
    /// the manifest.
    pub fn load(path: &Path) -> Result<LmSession, LmError> {
        let (manifest, onnx_path, bytes) = Manifest::load(path)?;
        let plan = Self::plan(&manifest, &bytes).map_err(|e| {
            LmError::invalid(onnx_path.display().to_string(), "graph", e.to_string())
        })?;
        Ok(LmSession { manifest, plan })
    }

    fn plan(manifest: &Manifest, bytes: &[u8]) -> TractResult<Plan> {
        let cfg = &manifest.config;
        let mut model = tract_onnx::onnx().model_for_read(&mut std::io::Cursor::new(bytes))?;
        let want_in = input_names(cfg);
        let want_out = output_names(cfg);
        let got_in: Vec<String> = model
            .input_outlets()?
            .iter()
            .map(|o| model.node(o.node).name.clone())
            .collect();
        if got_in != want_in || manifest.inputs != want_in || manifest.outputs != want_out {
            anyhow::bail!(
                "the graph's inputs {got_in:?} / manifest's {:?} are not the {want_in:?} that config implies",
                manifest.inputs
            );
        }
        let t = model.sym("T");
        let p = model.sym("P");
        let td: TDim = t.clone().into();
        let pd: TDim = p.clone().into();
        let s = pd.clone() + td.clone();
        let mut i = 0;
        model = model.with_input_fact(i, i64::fact([1.to_dim(), td.clone()]).into())?;
        i += 1;
        model = model.with_input_fact(i, i64::fact([1.to_dim(), td.clone()]).into())?;
        i += 1;
        if cfg.positions == PosScheme::FrameSlot {
            model = model.with_input_fact(i, i64::fact([1.to_dim(), td.clone()]).into())?;
            i += 1;
        }
        model = model.with_input_fact(i, f32::fact([td.clone(), s.clone()]).into())?;
        i += 1;
        let kv = [
            1.to_dim(),
            cfg.n_heads.to_dim(),
            pd.clone(),
            cfg.d_head().to_dim(),
        ];
        for _ in 0..2 * cfg.n_layers {
            model = model.with_input_fact(i, f32::fact(kv.clone()).into())?;
            i += 1;
        }
        model.into_optimized()?.into_runnable()
    }

    pub fn config(&self) -> &ModelConfig {
        &self.manifest.config
    }

    /// One step: feed `tokens` at `pos` after the cached `past`; returns the
    /// logits of every new token and the extended cache. Under the causal
    /// objective each new token sees the whole past and the new tokens up
    /// to itself; a masked model sees everything.
    pub fn step(&self, tokens: &[u32], pos: &[Pos], past: Kv) -> Result<(StepOut, Kv), LmError> {
        let cfg = &self.manifest.config;
        let n = tokens.len();
        if n == 0 || pos.len() != n {
            return Err(LmError::invalid(
                "request",
                "tokens",
                format!("{n} tokens, {} positions", pos.len()),
            ));
        }
        if let Some(&bad) = tokens.iter().find(|&&t| t as usize >= cfg.vocab_size) {
            return Err(LmError::invalid(
                "request",
                "tokens",
                format!("id {bad} outside the vocabulary ({})", cfg.vocab_size),
            ));
        }
        let (ta, tb) = (cfg.table_a() as i64, cfg.table_b().max(1) as i64);
        if let Some(q) = pos
            .iter()
            .find(|q| q.a < 0 || q.a >= ta || q.b < 0 || q.b >= tb)
        {
            return Err(LmError::invalid(
                "request",
                "positions",
                format!("{q:?} outside the position tables ({ta}, {tb})"),
            ));
        }
        let p = past.len;
        let s = p + n;
        let mut inputs: TVec<TValue> = TVec::new();
        let ids: Vec<i64> = tokens.iter().map(|&t| t as i64).collect();
        inputs.push(Tensor::from_shape(&[1, n], &ids).map_err(rt)?.into_tvalue());
        let a: Vec<i64> = pos.iter().map(|q| q.a).collect();
        inputs.push(Tensor::from_shape(&[1, n], &a).map_err(rt)?.into_tvalue());
        if cfg.positions == PosScheme::FrameSlot {
            let b: Vec<i64> = pos.iter().map(|q| q.b).collect();
            inputs.push(Tensor::from_shape(&[1, n], &b).map_err(rt)?.into_tvalue());
        }
        let bias = attention_bias(cfg.objective, p, n);
        inputs.push(
            Tensor::from_shape(&[n, s], &bias)
                .map_err(rt)?
                .into_tvalue(),
        );
        for (k, v) in past.layers {
            inputs.push(k.into_tvalue());
            inputs.push(v.into_tvalue());
        }
        let mut out = self.plan.run(inputs).map_err(rt)?;
        let nk = cfg.classes.len();
        let mut layers = Vec::with_capacity(cfg.n_layers);
        let rest: Vec<TValue> = out.drain(1 + nk..).collect();
        let mut it = rest.into_iter();
        while let (Some(k), Some(v)) = (it.next(), it.next()) {
            layers.push((k.into_tensor(), v.into_tensor()));
        }
        let flat = |t: &TValue| -> Result<Vec<f32>, LmError> {
            Ok(t.to_plain_array_view::<f32>()
                .map_err(rt)?
                .iter()
                .copied()
                .collect())
        };
        let logits = flat(&out[0])?;
        let class_logits = out[1..1 + nk].iter().map(flat).collect::<Result<_, _>>()?;
        Ok((
            StepOut {
                logits,
                class_logits,
            },
            Kv { layers, len: s },
        ))
    }
}

/// The additive attention bias for `n` new tokens after `past` cached ones:
/// 0 where a token may look, −1e9 where it may not. Shared with the trainer.
pub fn attention_bias(objective: Objective, past: usize, n: usize) -> Vec<f32> {
    let s = past + n;
    let mut b = vec![0f32; n * s];
    if objective == Objective::Causal {
        for i in 0..n {
            for j in past + i + 1..s {
                b[i * s + j] = -1e9;
            }
        }
    }
    b
}
