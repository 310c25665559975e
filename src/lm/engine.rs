//! The model runtime behind one small trait: a loaded ONNX graph
//! ([`Graph`]) spawns run states ([`GraphState`]), each owned by one
//! generator or request and reused from step to step. Two runtimes
//! implement it: tract (always built; `tract_rt.rs`) and onnxruntime through `ort`
//! (cargo feature `onnxruntime`, loaded at run time from the library the
//! `onnxruntime` pip wheel ships). The frame model, the learned
//! in-betweener and, on onnxruntime, the flat GPT run through it (the flat
//! GPT's graph has dynamic shapes: a state takes whatever shapes a step
//! brings; on tract it keeps a plan with symbolic dimensions in
//! `runtime.rs`).
//!
//! The frame model's local step, which runs 42 times a frame, has a third
//! implementation of the same trait: choreo's own kernel
//! ([`local_kernel`]), used on either runtime where it reproduces the
//! graph (checked at load).
//!
//! Key/value caches of fixed capacity ([`Cache`]) live beside the states:
//! a step passes them by reference (no copy in either runtime) and writes
//! the new position's rows in place.

use super::LmError;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tract_onnx::prelude::*;

fn rt(e: impl std::fmt::Display) -> LmError {
    LmError::Runtime(e.to_string())
}

/// Which runtime runs the graphs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Runtime {
    Tract,
    Ort,
    /// A choice, not an engine's runtime: onnxruntime where its library
    /// loads (a build with the `onnxruntime` feature, --ort-lib or
    /// ORT_DYLIB_PATH), else tract ([`Engine::new`] says why).
    Auto,
}

impl Runtime {
    pub fn name(self) -> &'static str {
        match self {
            Runtime::Tract => "tract",
            Runtime::Ort => "ort",
            Runtime::Auto => "auto",
        }
    }
}

impl std::str::FromStr for Runtime {
    type Err = String;
    fn from_str(s: &str) -> Result<Runtime, String> {
        match s {
            "tract" => Ok(Runtime::Tract),
            "ort" | "onnxruntime" => Ok(Runtime::Ort),
            "auto" => Ok(Runtime::Auto),
            other => Err(format!(
                "unknown runtime {other:?}: expected tract, ort or auto"
            )),
        }
    }
}

/// What runs the frame model's local step ([`Engine::with_local_step`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LocalStep {
    /// choreo's own kernel ([`local_kernel`]), where it reproduces the graph.
    Kernel,
    /// The runtime's run of the exported graph.
    Graph,
}

impl std::str::FromStr for LocalStep {
    type Err = String;
    fn from_str(s: &str) -> Result<LocalStep, String> {
        match s {
            "kernel" => Ok(LocalStep::Kernel),
            "graph" => Ok(LocalStep::Graph),
            other => Err(format!(
                "unknown local step {other:?}: expected kernel or graph"
            )),
        }
    }
}

/// One input of a step: a shape and its row-major data.
pub enum In<'a> {
    F32(&'a [usize], &'a [f32]),
    I64(&'a [usize], &'a [i64]),
}

/// A step's outputs, all `f32`: shape and data per output, in the graph's
/// order. The buffers are reused from step to step.
#[derive(Default)]
pub struct Outputs(pub Vec<(Vec<usize>, Vec<f32>)>);

impl Outputs {
    pub fn data(&self, i: usize) -> &[f32] {
        &self.0[i].1
    }
    fn set(&mut self, i: usize, shape: &[usize], data: &[f32]) {
        if self.0.len() <= i {
            self.0.resize_with(i + 1, Default::default);
        }
        let (s, d) = &mut self.0[i];
        s.clear();
        s.extend_from_slice(shape);
        d.clear();
        d.extend_from_slice(data);
    }
}

/// Key/value caches of fixed capacity, `[batch, heads, cap, d_head]` per layer,
/// and how many rows hold positions. Passed to a step after its other
/// inputs, as (k, v) per layer. A clone shares the tensors until either
/// side writes (copy on write), so forking a generation is cheap.
#[derive(Clone)]
pub struct Cache {
    k: Vec<Arc<Tensor>>,
    v: Vec<Arc<Tensor>>,
    /// Rows side by side (a batched graph's batch; else 1).
    batch: usize,
    heads: usize,
    cap: usize,
    dh: usize,
    len: usize,
    /// The attention bias over `cap + 1` keys, kept in step with `len`: 0
    /// over the filled rows and the new position (last), −1e9 elsewhere.
    bias: Vec<f32>,
}

impl Cache {
    pub fn new(layers: usize, heads: usize, cap: usize, dh: usize) -> Cache {
        Cache::batched(1, layers, heads, cap, dh)
    }

    /// `batch` caches side by side (`[batch, heads, cap, d_head]` per
    /// layer) for a batched graph; the positions advance together.
    pub fn batched(batch: usize, layers: usize, heads: usize, cap: usize, dh: usize) -> Cache {
        let z = || Arc::new(Tensor::zero::<f32>(&[batch, heads, cap, dh]).expect("cache tensor"));
        Cache {
            k: (0..layers).map(|_| z()).collect(),
            v: (0..layers).map(|_| z()).collect(),
            batch,
            heads,
            cap,
            dh,
            len: 0,
            bias: (0..=cap)
                .map(|i| if i == cap { 0.0 } else { -1e9 })
                .collect(),
        }
    }

    /// Positions held.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The attention bias over `cap + 1` keys: 0 over the filled rows and
    /// the new position (last), −1e9 elsewhere.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }

    /// Forgets the newest position (its rows are masked, then overwritten).
    pub fn pop(&mut self) {
        if self.len > 0 {
            self.len -= 1;
            self.bias[self.len] = -1e9;
        }
    }

    fn shape(&self) -> [usize; 4] {
        [self.batch, self.heads, self.cap, self.dh]
    }

    /// The caches' tensors in input order (k, v per layer).
    fn tensors(&self) -> impl Iterator<Item = &Arc<Tensor>> {
        self.k.iter().zip(&self.v).flat_map(|(k, v)| [k, v])
    }

    /// Writes the new position's keys and values (`[batch, heads, 1, dh]`
    /// each, alternating k, v per layer: a step's last outputs) at row
    /// `len`.
    pub fn push(&mut self, out: &Outputs, first: usize) -> Result<(), LmError> {
        let (p, dh, cap) = (self.len, self.dh, self.cap);
        if p >= cap {
            return Err(rt("cache full"));
        }
        for l in 0..self.k.len() {
            for (j, dst) in [&mut self.k[l], &mut self.v[l]].into_iter().enumerate() {
                let src = out.data(first + 2 * l + j);
                let t = Arc::make_mut(dst);
                let mut view = t.to_plain_array_view_mut::<f32>().map_err(rt)?;
                let d = view
                    .as_slice_mut()
                    .ok_or_else(|| rt("cache tensor is not contiguous"))?;
                if src.len() != self.batch * self.heads * dh {
                    return Err(rt(format!(
                        "a step gave {} key/value numbers, the cache wants {}",
                        src.len(),
                        self.batch * self.heads * dh
                    )));
                }
                for h in 0..self.batch * self.heads {
                    d[(h * cap + p) * dh..(h * cap + p + 1) * dh]
                        .copy_from_slice(&src[h * dh..(h + 1) * dh]);
                }
            }
        }
        self.bias[p] = 0.0;
        self.len += 1;
        Ok(())
    }
}

/// A loaded graph, shared by requests.
pub trait Graph: Send + Sync {
    /// A fresh run state (one per generator or request; reused per step).
    /// A graph with a batch symbol ([`GraphSpec::batch`]) runs it at 1.
    fn spawn(&self) -> Result<Box<dyn GraphState>, LmError>;

    /// Whether the graph was exported with the batch symbol
    /// [`GraphSpec::batch`] names (rows side by side).
    fn batches(&self) -> bool {
        false
    }

    /// A run state for `n` rows side by side, if [`Graph::batches`]; None
    /// otherwise.
    fn spawn_batch(&self, _n: usize) -> Result<Option<Box<dyn GraphState>>, LmError> {
        Ok(None)
    }
}

/// A graph's run state.
pub trait GraphState: Send {
    /// Runs one step on `inputs` (graph order) followed by `cache`'s
    /// tensors, writing every output into `out`.
    fn run(
        &mut self,
        inputs: &[In<'_>],
        cache: Option<&Cache>,
        out: &mut Outputs,
    ) -> Result<(), LmError>;
}

/// A dimension of an input's shape: fixed, or a named symbol (a batch).
#[derive(Clone, Debug)]
pub enum Dim {
    N(usize),
    Sym(&'static str),
}

/// The inputs a graph must take and the number of outputs it must give,
/// checked at load time; optional `f32` input shapes, pinned for tract
/// before it optimises (for graphs exported with symbolic dimensions).
pub struct GraphSpec<'a> {
    pub inputs: &'a [String],
    pub outputs: usize,
    /// Where the graph came from, for errors.
    pub file: &'a str,
    pub f32_shapes: &'a [Vec<Dim>],
    /// The symbol of a batch dimension the graph may have (its first
    /// input's first dimension): a graph exported with it runs at any
    /// batch ([`Graph::spawn_batch`]); one exported at a fixed 1 still loads.
    pub batch: Option<&'a str>,
}

/// Whether the graph's first input has the batch symbol `sym` as its first
/// dimension.
fn has_batch(bytes: &[u8], sym: &str) -> bool {
    use prost::Message;
    use tract_onnx::pb::{tensor_shape_proto::dimension::Value, type_proto};
    let Ok(m) = tract_onnx::pb::ModelProto::decode(bytes) else {
        return false;
    };
    let first = m
        .graph
        .as_ref()
        .and_then(|g| g.input.first())
        .and_then(|i| i.r#type.as_ref())
        .and_then(|t| match &t.value {
            Some(type_proto::Value::TensorType(t)) => t.shape.as_ref(),
            _ => None,
        })
        .and_then(|s| s.dim.first())
        .and_then(|d| d.value.as_ref());
    matches!(first, Some(Value::DimParam(p)) if p == sym)
}

/// What loads graphs: the runtime and, for ort, its environment.
#[derive(Clone)]
pub struct Engine {
    runtime: Runtime,
    /// What runs the frame model's local step: choreo's own kernel (where
    /// it reproduces the graph; [`local_kernel::checked`]) or the runtime.
    local_step: LocalStep,
    #[cfg(feature = "onnxruntime")]
    ort: Option<Arc<ort_rt::OrtEnv>>,
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Engine({})", self.runtime.name())
    }
}

impl Engine {
    pub fn tract() -> Engine {
        Engine {
            runtime: Runtime::Tract,
            local_step: LocalStep::Kernel,
            #[cfg(feature = "onnxruntime")]
            ort: None,
        }
    }

    /// The engine for `runtime`; for ort, the library at `lib`, else
    /// `ORT_DYLIB_PATH`. Fails with the fix when the library is missing,
    /// unloadable or of an unsupported version, or when this build lacks
    /// the `onnxruntime` feature.
    pub fn new(runtime: Runtime, lib: Option<&Path>) -> Result<Engine, LmError> {
        match runtime {
            Runtime::Tract => Ok(Engine::tract()),
            Runtime::Ort => Engine::ort(lib),
            Runtime::Auto => {
                let (e, why) = Engine::auto(lib);
                if let Some(why) = why {
                    tracing::info!(
                        "--runtime auto: tract, as onnxruntime is not available ({why})"
                    );
                }
                Ok(e)
            }
        }
    }

    /// `Runtime::Auto`: onnxruntime (the faster on this kind of machine,
    /// bench/RESULTS.md "Model runtime") where its library loads, else
    /// tract, with the reason onnxruntime was passed over.
    pub fn auto(lib: Option<&Path>) -> (Engine, Option<String>) {
        match Engine::ort(lib) {
            Ok(e) => (e, None),
            Err(e) => (Engine::tract(), Some(e.to_string())),
        }
    }

    #[cfg(not(feature = "onnxruntime"))]
    fn ort(_lib: Option<&Path>) -> Result<Engine, LmError> {
        Err(LmError::Runtime(
            "--runtime ort: this build has no onnxruntime support; rebuild with `cargo build --release --features onnxruntime` (the image and the default build are tract-only)".into(),
        ))
    }

    #[cfg(feature = "onnxruntime")]
    fn ort(lib: Option<&Path>) -> Result<Engine, LmError> {
        let env = ort_rt::OrtEnv::open(&ort_library(lib)?)?;
        Ok(Engine {
            runtime: Runtime::Ort,
            local_step: LocalStep::Kernel,
            ort: Some(env),
        })
    }

    pub fn runtime(&self) -> Runtime {
        self.runtime
    }

    /// This engine with the frame model's local step on choreo's kernel
    /// (the default) or on the runtime's own run of the graph.
    pub fn with_local_step(mut self, step: LocalStep) -> Engine {
        self.local_step = step;
        self
    }

    pub fn local_step(&self) -> LocalStep {
        self.local_step
    }

    /// Loads an ONNX graph (static shapes, as the trainer exports them),
    /// checking its input names and output count against `spec`.
    pub fn load(&self, bytes: &[u8], spec: &GraphSpec) -> Result<Arc<dyn Graph>, LmError> {
        let batch = spec.batch.filter(|s| has_batch(bytes, s));
        match self.runtime {
            // An engine's runtime is never Auto (Engine::new resolves it).
            Runtime::Tract | Runtime::Auto => tract_rt::load(bytes, spec, batch),
            Runtime::Ort => {
                #[cfg(feature = "onnxruntime")]
                {
                    let env = self.ort.clone().expect("ort engine has an environment");
                    Ok(Arc::new(ort_rt::OrtGraph::load(
                        env,
                        bytes,
                        spec,
                        batch.is_some(),
                    )?))
                }
                #[cfg(not(feature = "onnxruntime"))]
                unreachable!("an ort engine is only built with the onnxruntime feature")
            }
        }
    }
}

/// The library `--runtime ort` loads: the flag, else `ORT_DYLIB_PATH`.
pub fn ort_library(lib: Option<&Path>) -> Result<PathBuf, LmError> {
    const HOW: &str = "install the onnxruntime 1.32 wheel (`pip install -r scripts/requirements.txt`) and point ORT_DYLIB_PATH (or --ort-lib) at site-packages/onnxruntime/capi/libonnxruntime.so.*";
    let path = match lib {
        Some(p) => p.to_path_buf(),
        None => match std::env::var_os("ORT_DYLIB_PATH") {
            Some(p) if !p.is_empty() => PathBuf::from(p),
            _ => {
                return Err(LmError::Runtime(format!(
                    "--runtime ort: no onnxruntime library given; {HOW}"
                )))
            }
        },
    };
    if !path.is_file() {
        return Err(LmError::Runtime(format!(
            "--runtime ort: {}: no such file; {HOW}",
            path.display()
        )));
    }
    Ok(path)
}

pub(crate) mod kernels;
pub mod local_kernel;
#[cfg(feature = "onnxruntime")]
mod ort_rt;
mod softmax;
mod tract_rt;
pub(crate) use tract_rt::clean_upper_state;
