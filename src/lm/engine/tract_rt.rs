//! The tract side of the engine (built in): one optimised plan per graph,
//! or per batch size where the graph has a batch symbol; each operator's
//! run followed by a clean-up of the vector registers.

use super::{rt, softmax, Cache, Dim, Graph, GraphSpec, GraphState, In, LmError, Outputs};
use std::sync::Arc;
use tract_onnx::prelude::*;

/// Loads a graph on tract (`batch`: its batch symbol, where it has one),
/// checking its input names and output count against `spec`.
pub(super) fn load(
    bytes: &[u8],
    spec: &GraphSpec,
    batch: Option<&str>,
) -> Result<Arc<dyn Graph>, LmError> {
    let bad = |e: String| LmError::invalid(spec.file, "graph", e);
    let model = tract_onnx::onnx()
        .model_for_read(&mut std::io::Cursor::new(bytes))
        .map_err(|e| bad(e.to_string()))?;
    check_names(&model, spec).map_err(|e| bad(e.to_string()))?;
    let model = pin_shapes(model, spec.f32_shapes).map_err(|e| bad(e.to_string()))?;
    let typed = model
        .into_typed()
        .and_then(|m| m.into_decluttered())
        .and_then(softmax::rows_by_plain_code)
        .map_err(|e| bad(e.to_string()))?;
    if let Some(sym) = batch {
        let sym = typed.sym(sym);
        let g = TractBatched {
            typed,
            sym,
            plans: Default::default(),
        };
        g.plan(1).map_err(|e| bad(e.to_string()))?;
        return Ok(Arc::new(g));
    }
    let plan = typed
        .into_optimized()
        .and_then(|m| m.into_runnable())
        .map_err(|e| bad(e.to_string()))?;
    Ok(Arc::new(TractGraph(plan)))
}

fn check_names(model: &tract_onnx::prelude::InferenceModel, spec: &GraphSpec) -> TractResult<()> {
    let got_in: Vec<String> = model
        .input_outlets()?
        .iter()
        .map(|o| model.node(o.node).name.clone())
        .collect();
    let got_out = model.output_outlets()?.len();
    if got_in != spec.inputs || got_out != spec.outputs {
        anyhow::bail!(
            "the graph's inputs {got_in:?} (and {got_out} outputs) are not the {:?} (and {} outputs) the manifest's config implies",
            spec.inputs,
            spec.outputs
        );
    }
    Ok(())
}

fn pin_shapes(mut model: InferenceModel, shapes: &[Vec<Dim>]) -> TractResult<InferenceModel> {
    for (i, dims) in shapes.iter().enumerate() {
        let dims: Vec<TDim> = dims
            .iter()
            .map(|d| match d {
                Dim::N(n) => n.to_dim(),
                Dim::Sym(s) => model.sym(s).into(),
            })
            .collect();
        model = model.with_input_fact(i, f32::fact(dims).into())?;
    }
    Ok(model)
}

struct TractGraph(Arc<TypedRunnableModel>);

impl Graph for TractGraph {
    fn spawn(&self) -> Result<Box<dyn GraphState>, LmError> {
        Ok(Box::new(TractState(self.0.spawn().map_err(rt)?)))
    }
}

/// A tract graph with a batch symbol: one plan per batch size, each
/// optimised for it when first asked for (a few milliseconds).
struct TractBatched {
    typed: TypedModel,
    sym: Symbol,
    plans: std::sync::Mutex<std::collections::HashMap<usize, Arc<TypedRunnableModel>>>,
}

impl TractBatched {
    fn plan(&self, n: usize) -> TractResult<Arc<TypedRunnableModel>> {
        let mut plans = self
            .plans
            .lock()
            .map_err(|_| anyhow::anyhow!("plan cache poisoned"))?;
        if let Some(p) = plans.get(&n) {
            return Ok(p.clone());
        }
        let subs = std::iter::once((self.sym.clone(), TDim::Val(n as i64))).collect();
        let p = self
            .typed
            .set_symbols(&subs)?
            .into_optimized()?
            .into_runnable()?;
        plans.insert(n, p.clone());
        Ok(p)
    }
}

impl Graph for TractBatched {
    fn spawn(&self) -> Result<Box<dyn GraphState>, LmError> {
        Ok(Box::new(TractState(
            self.plan(1).map_err(rt)?.spawn().map_err(rt)?,
        )))
    }

    fn batches(&self) -> bool {
        true
    }

    fn spawn_batch(&self, n: usize) -> Result<Option<Box<dyn GraphState>>, LmError> {
        let st = self.plan(n).map_err(rt)?.spawn().map_err(rt)?;
        Ok(Some(Box::new(TractState(st))))
    }
}

struct TractState(TypedSimpleState);

/// Marks the vector registers' upper halves clean (`vzeroupper`); called
/// after each operator tract runs (and after each flat-GPT step). tract's
/// AVX-512 matrix kernels return with them dirty, and until something
/// clears them every SSE instruction that follows pays for a merge with
/// the stale upper half: this crate is built for baseline x86-64, so
/// choreo's drawing, scoring and posture work between two steps, and
/// tract's own code between two kernels, ran slowed. On the bundled frame
/// model the labelled default's frame on tract went from 11.8–12.0 to
/// 8.9–9.6 ms p50 cleaning after each run, 9.2–9.3 after each operator
/// (bench/RESULTS.md, "tract's dirty upper registers"). onnxruntime
/// returns with them clean.
#[inline]
pub(crate) fn clean_upper_state() {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX (checked above); `vzeroupper` only
        // zeroes the registers' upper halves, which hold nothing live
        // between two calls into tract.
        unsafe { std::arch::x86_64::_mm256_zeroupper() }
    }
}

impl GraphState for TractState {
    fn run(
        &mut self,
        inputs: &[In<'_>],
        cache: Option<&Cache>,
        out: &mut Outputs,
    ) -> Result<(), LmError> {
        let mut tv: TVec<TValue> = tvec![];
        for i in inputs {
            let t = match i {
                In::F32(s, d) => Tensor::from_shape(s, d),
                In::I64(s, d) => Tensor::from_shape(s, d),
            }
            .map_err(rt)?;
            tv.push(t.into_tvalue());
        }
        if let Some(c) = cache {
            for t in c.tensors() {
                tv.push(TValue::from_const(t.clone()));
            }
        }
        // Each operator as tract runs it, the upper registers cleaned after
        // it; the turn's values (the cache tensors' clones among them) are
        // dropped at the end, so the next in-place write to a cache does not
        // copy it.
        let res = self
            .0
            .run_plan_with_eval(tv, |ctx, st, node, input| {
                let r = tract_onnx::tract_core::plan::eval(ctx, st, node, input);
                clean_upper_state();
                r
            })
            .map_err(rt)?;
        for (i, t) in res.iter().enumerate() {
            let data = t
                .try_as_plain_ram()
                .map_err(rt)?
                .as_slice::<f32>()
                .map_err(rt)?;
            out.set(i, t.shape(), data);
        }
        out.0.truncate(res.len());
        Ok(())
    }
}
