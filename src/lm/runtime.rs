//! The thesis's flat GPT at run time: one forward step over new tokens,
//! with the past keys and values as inputs and the extended ones as
//! outputs, so a stream costs one step per token rather than one window.
//! Its graph has dynamic shapes (the past grows), so tract gets a plan with
//! symbolic dimensions here, and onnxruntime runs it through the engine's
//! graph trait (`--runtime ort`), whose states take any input shape.

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
    backend: Backend,
}

/// Which runtime runs the graph.
enum Backend {
    Tract(Plan),
    Engine(Arc<dyn super::engine::Graph>),
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
        LmSession::load_with(path, &super::engine::Engine::tract())
    }

    /// Loads it on `engine`'s runtime (tract: a plan with symbolic
    /// dimensions; onnxruntime: the engine's graph, dynamic shapes as is).
    pub fn load_with(path: &Path, engine: &super::engine::Engine) -> Result<LmSession, LmError> {
        let (manifest, onnx_path, bytes) = Manifest::load(path)?;
        let file = onnx_path.display().to_string();
        let backend = match engine.runtime() {
            super::engine::Runtime::Tract => Backend::Tract(
                Self::plan(&manifest, &bytes)
                    .map_err(|e| LmError::invalid(file.clone(), "graph", e.to_string()))?,
            ),
            _ => {
                let cfg = &manifest.config;
                let inputs = input_names(cfg);
                if manifest.inputs != inputs || manifest.outputs != output_names(cfg) {
                    return Err(LmError::invalid(
                        file,
                        "graph",
                        format!(
                            "the manifest's inputs {:?} are not the {inputs:?} that config implies",
                            manifest.inputs
                        ),
                    ));
                }
                let spec = super::engine::GraphSpec {
                    inputs: &inputs,
                    outputs: output_names(cfg).len(),
                    file: &file,
                    f32_shapes: &[],
                    batch: None,
                };
                Backend::Engine(engine.load(&bytes, &spec)?)
            }
        };
        Ok(LmSession { manifest, backend })
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
        let ids: Vec<i64> = tokens.iter().map(|&t| t as i64).collect();
        let a: Vec<i64> = pos.iter().map(|q| q.a).collect();
        let b: Vec<i64> = pos.iter().map(|q| q.b).collect();
        let bias = attention_bias(cfg.objective, p, n);
        let nk = cfg.classes.len();
        match &self.backend {
            Backend::Tract(plan) => {
                let mut inputs: TVec<TValue> = TVec::new();
                inputs.push(Tensor::from_shape(&[1, n], &ids).map_err(rt)?.into_tvalue());
                inputs.push(Tensor::from_shape(&[1, n], &a).map_err(rt)?.into_tvalue());
                if cfg.positions == PosScheme::FrameSlot {
                    inputs.push(Tensor::from_shape(&[1, n], &b).map_err(rt)?.into_tvalue());
                }
                inputs.push(
                    Tensor::from_shape(&[n, s], &bias)
                        .map_err(rt)?
                        .into_tvalue(),
                );
                for (k, v) in past.layers {
                    inputs.push(k.into_tvalue());
                    inputs.push(v.into_tvalue());
                }
                let mut out = plan.run(inputs).map_err(rt)?;
                super::engine::clean_upper_state();
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
            Backend::Engine(graph) => {
                use super::engine::{In, Outputs};
                let row = [1, n];
                let bias_shape = [n, s];
                let kv_shape = [1, cfg.n_heads, p, cfg.d_head()];
                let past_data = past
                    .layers
                    .iter()
                    .map(|(k, v)| {
                        Ok((
                            k.try_as_plain_ram()
                                .map_err(rt)?
                                .as_slice::<f32>()
                                .map_err(rt)?,
                            v.try_as_plain_ram()
                                .map_err(rt)?
                                .as_slice::<f32>()
                                .map_err(rt)?,
                        ))
                    })
                    .collect::<Result<Vec<_>, LmError>>()?;
                let mut inputs = vec![In::I64(&row, &ids), In::I64(&row, &a)];
                if cfg.positions == PosScheme::FrameSlot {
                    inputs.push(In::I64(&row, &b));
                }
                inputs.push(In::F32(&bias_shape, &bias));
                for (k, v) in &past_data {
                    inputs.push(In::F32(&kv_shape, k));
                    inputs.push(In::F32(&kv_shape, v));
                }
                let mut out = Outputs::default();
                graph.spawn()?.run(&inputs, None, &mut out)?;
                let tensor = |i: usize| -> Result<Tensor, LmError> {
                    let (shape, data) = &out.0[i];
                    Tensor::from_shape(shape, data).map_err(rt)
                };
                let mut layers = Vec::with_capacity(cfg.n_layers);
                for l in 0..cfg.n_layers {
                    layers.push((tensor(1 + nk + 2 * l)?, tensor(2 + nk + 2 * l)?));
                }
                Ok((
                    StepOut {
                        logits: out.data(0).to_vec(),
                        class_logits: (1..1 + nk).map(|i| out.data(i).to_vec()).collect(),
                    },
                    Kv { layers, len: s },
                ))
            }
        }
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
