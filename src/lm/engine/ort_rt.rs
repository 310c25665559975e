//! The onnxruntime side of the engine (cargo feature `onnxruntime`):
//! one environment per process, a pool of sessions per graph.

use super::{rt, Cache, Graph, GraphSpec, GraphState, In, LmError, Outputs};
use ort::session::Session;
use ort::value::TensorRef;
use std::path::Path;
use std::sync::{Arc, Mutex};

/// The loaded library's environment. onnxruntime allows one per
/// process, so it is made once and shared by every engine; asking for a
/// different library afterwards is an error.
pub struct OrtEnv(ort::environment::Environment);

static ENV: Mutex<Option<(std::path::PathBuf, Arc<OrtEnv>)>> = Mutex::new(None);

impl OrtEnv {
    pub fn open(path: &Path) -> Result<Arc<OrtEnv>, LmError> {
        let shown = path.display().to_string();
        let mut env = ENV.lock().map_err(rt)?;
        if let Some((p, e)) = env.as_ref() {
            if p.as_path() == path {
                return Ok(e.clone());
            }
            return Err(LmError::Runtime(format!(
                "--runtime ort: {shown}: cannot load onnxruntime: this process already runs the one at {}",
                p.display()
            )));
        }
        // ort panics when the library lacks the API version it wants
        // (an older onnxruntime); turn that into a start-up error.
        let p = path.to_path_buf();
        let built = std::panic::catch_unwind(move || -> Result<_, String> {
            let b = ort::init_from(&p).map_err(|e| e.to_string())?;
            let env = b.with_name("choreo").build().map_err(|e| e.to_string())?;
            let _ = ort::info();
            Ok(env)
        });
        match built {
            Ok(Ok(e)) => {
                let e = Arc::new(OrtEnv(e));
                *env = Some((path.to_path_buf(), e.clone()));
                Ok(e)
            }
            Ok(Err(e)) => Err(LmError::Runtime(format!(
                "--runtime ort: {shown}: cannot load onnxruntime: {e}; install the onnxruntime 1.32 wheel (pip install -r scripts/requirements.txt)"
            ))),
            Err(_) => Err(LmError::Runtime(format!(
                "--runtime ort: {shown}: not an onnxruntime this build supports (it needs API version {} or later, onnxruntime 1.{} or newer); install the onnxruntime 1.32 wheel (pip install -r scripts/requirements.txt)",
                ort::MINOR_VERSION, ort::MINOR_VERSION
            ))),
        }
    }
}

/// A graph on ort: the model bytes and a pool of sessions (ort runs a
/// session through `&mut`, so each live state holds one).
pub struct OrtGraph {
    env: Arc<OrtEnv>,
    bytes: Arc<[u8]>,
    pool: Arc<Mutex<Vec<Session>>>,
    /// Exported with a batch symbol: a session runs any batch.
    batched: bool,
}

fn session(env: &OrtEnv, bytes: &[u8]) -> Result<Session, LmError> {
    Session::builder(&env.0)
        .map_err(rt)?
        .with_intra_threads(1)
        .map_err(rt)?
        .with_inter_threads(1)
        .map_err(rt)?
        .commit_from_memory(bytes)
        .map_err(rt)
}

impl OrtGraph {
    pub fn load(
        env: Arc<OrtEnv>,
        bytes: &[u8],
        spec: &GraphSpec,
        batched: bool,
    ) -> Result<OrtGraph, LmError> {
        let s = session(&env, bytes)
            .map_err(|e| LmError::invalid(spec.file, "graph", e.to_string()))?;
        let got: Vec<String> = s.inputs().iter().map(|o| o.name().to_string()).collect();
        if got != spec.inputs || s.outputs().len() != spec.outputs {
            return Err(LmError::invalid(
                spec.file,
                "graph",
                format!(
                    "the graph's inputs {got:?} (and {} outputs) are not the {:?} (and {} outputs) the manifest's config implies",
                    s.outputs().len(),
                    spec.inputs,
                    spec.outputs
                ),
            ));
        }
        Ok(OrtGraph {
            env,
            bytes: bytes.into(),
            pool: Arc::new(Mutex::new(vec![s])),
            batched,
        })
    }
}

impl Graph for OrtGraph {
    fn spawn(&self) -> Result<Box<dyn GraphState>, LmError> {
        let pooled = self.pool.lock().map_err(rt)?.pop();
        let s = match pooled {
            Some(s) => s,
            None => session(&self.env, &self.bytes)?,
        };
        Ok(Box::new(OrtState {
            session: Some(s),
            pool: self.pool.clone(),
        }))
    }

    fn batches(&self) -> bool {
        self.batched
    }

    fn spawn_batch(&self, _n: usize) -> Result<Option<Box<dyn GraphState>>, LmError> {
        if self.batched {
            self.spawn().map(Some)
        } else {
            Ok(None)
        }
    }
}

struct OrtState {
    session: Option<Session>,
    pool: Arc<Mutex<Vec<Session>>>,
}

impl Drop for OrtState {
    fn drop(&mut self) {
        if let (Some(s), Ok(mut p)) = (self.session.take(), self.pool.lock()) {
            p.push(s);
        }
    }
}

impl GraphState for OrtState {
    fn run(
        &mut self,
        inputs: &[In<'_>],
        cache: Option<&Cache>,
        out: &mut Outputs,
    ) -> Result<(), LmError> {
        let session = self.session.as_mut().expect("state holds a session");
        let mut vals: Vec<ort::session::SessionInputValue<'_>> = Vec::with_capacity(16);
        for i in inputs {
            vals.push(match i {
                In::F32(s, d) => TensorRef::from_array_view((s.to_vec(), *d))
                    .map_err(rt)?
                    .into(),
                In::I64(s, d) => TensorRef::from_array_view((s.to_vec(), *d))
                    .map_err(rt)?
                    .into(),
            });
        }
        if let Some(c) = cache {
            let shape = c.shape().to_vec();
            for t in c.tensors() {
                let d = t
                    .try_as_plain_ram()
                    .map_err(rt)?
                    .as_slice::<f32>()
                    .map_err(rt)?;
                vals.push(
                    TensorRef::from_array_view((shape.clone(), d))
                        .map_err(rt)?
                        .into(),
                );
            }
        }
        let res = session.run(vals.as_slice()).map_err(rt)?;
        let n = res.len();
        for i in 0..n {
            let (shape, data) = res[i].try_extract_tensor::<f32>().map_err(rt)?;
            let shape: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
            out.set(i, &shape, data);
        }
        out.0.truncate(n);
        Ok(())
    }
}
