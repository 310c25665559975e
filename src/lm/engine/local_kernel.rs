//! choreo's own kernel for the frame model's local step: the small
//! decoder that runs once a slot (42 times a frame) for every candidate
//! frame side by side. On tract its batch-4 step cost 0.14 ms for about
//! 0.6 million multiply-adds: ~115 operators, each product with its
//! inputs packed first and each costing microseconds whatever its size
//! (bench/RESULTS.md, "tract's operators one by one"). Here the same step
//! is plain loops over the graph's own weights ([`super::kernels`]):
//! row-major products whose inner loop the compiler vectorises (AVX2 and
//! FMA where the CPU has them, picked at run time; SSE otherwise), the
//! keys and values read in place from the caches, and the global state's
//! projection (the same for every slot of a frame) computed once a frame
//! instead of once a slot.
//!
//! It reads the weights from the exported local graph (the trainer's
//! `row_blocks` form: pre-LN blocks, fused query/key/value, GELU in its
//! erf form) and is only used where it reproduces that graph: at load,
//! [`checked`] runs both on the same probe steps and keeps the graph's
//! runtime when any output differs by more than [`PROBE_TOLERANCE`].

use super::kernels::{dot, gelu, gemm, layer_norm};
use super::softmax::softmax_rows;
use super::{Cache, Graph, GraphState, In, LmError, Outputs};
use std::sync::Arc;

/// How far (absolute, on logits and keys/values of order 1–10) the
/// kernel's outputs may lie from the graph's on the load-time probe: f32
/// round-off of a different summation order is ~1e-5; a wrong weight or
/// layout is ~1e-1 or more.
pub const PROBE_TOLERANCE: f32 = 1e-3;

fn bad(e: impl std::fmt::Display) -> LmError {
    LmError::Runtime(format!("local kernel: {e}"))
}

/// A graph's float initialisers by name: shape and data.
struct Initialisers(std::collections::HashMap<String, (Vec<usize>, Vec<f32>)>);

impl Initialisers {
    /// The weight `name`, whose shape must match `want` (None: any size).
    fn take(
        &mut self,
        name: &str,
        want: &[Option<usize>],
    ) -> Result<(Vec<usize>, Vec<f32>), LmError> {
        let (dims, data) = self
            .0
            .remove(name)
            .ok_or_else(|| bad(format!("the graph has no weight {name}")))?;
        let fits = dims.len() == want.len()
            && dims
                .iter()
                .zip(want)
                .all(|(d, w)| w.is_none_or(|w| w == *d));
        if !fits {
            return Err(bad(format!("{name} is {dims:?}, not {want:?}")));
        }
        Ok((dims, data))
    }

    fn vec(&mut self, name: &str, n: usize) -> Result<Vec<f32>, LmError> {
        Ok(self.take(name, &[Some(n)])?.1)
    }

    /// `{pre}.w` (`[n_in, n_out]`) and `{pre}.b`.
    fn linear(
        &mut self,
        pre: &str,
        n_in: usize,
        n_out: Option<usize>,
    ) -> Result<(Vec<f32>, Vec<f32>), LmError> {
        let (dims, w) = self.take(&format!("{pre}.w"), &[Some(n_in), n_out])?;
        Ok((w, self.vec(&format!("{pre}.b"), dims[1])?))
    }
}

/// A pre-LN block's weights (`[in, out]` matrices, row-major).
struct Block {
    ln1: (Vec<f32>, Vec<f32>),
    qkv: (Vec<f32>, Vec<f32>),
    o: (Vec<f32>, Vec<f32>),
    ln2: (Vec<f32>, Vec<f32>),
    fc1: (Vec<f32>, Vec<f32>),
    fc2: (Vec<f32>, Vec<f32>),
}

/// The local decoder's weights and sizes.
struct Weights {
    d_global: usize,
    d: usize,
    heads: usize,
    eps: f32,
    /// Rows of the three id tables (change ids, velocity ids, previous
    /// bins) and of the slot positions.
    rows: [usize; 4],
    ctx: (Vec<f32>, Vec<f32>),
    emb_in: Vec<f32>,
    emb_vel: Vec<f32>,
    emb_prev: Vec<f32>,
    pos: Vec<f32>,
    blocks: Vec<Block>,
    ln: (Vec<f32>, Vec<f32>),
    rel: (Vec<f32>, Vec<f32>),
    abs: (Vec<f32>, Vec<f32>),
}

/// The local step on choreo's kernel.
pub struct LocalKernel(Arc<Weights>);

impl LocalKernel {
    /// Reads the weights from a local step graph's bytes (`layers` blocks
    /// of `heads` heads, LayerNorm's `eps`); an error names what is
    /// missing or mis-shaped.
    pub fn from_onnx(bytes: &[u8], layers: usize, heads: usize, eps: f32) -> Result<Self, LmError> {
        use prost::Message;
        let m = tract_onnx::pb::ModelProto::decode(bytes).map_err(bad)?;
        let g = m.graph.ok_or_else(|| bad("no graph"))?;
        let mut t = std::collections::HashMap::new();
        for init in g.initializer {
            // ONNX's FLOAT = 1, stored as raw little-endian bytes.
            if init.data_type != 1 {
                continue;
            }
            let data: Vec<f32> = if !init.raw_data.is_empty() {
                init.raw_data
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect()
            } else {
                init.float_data.clone()
            };
            let dims: Vec<usize> = init.dims.iter().map(|&d| d as usize).collect();
            if data.len() != dims.iter().product::<usize>() {
                return Err(bad(format!(
                    "{} holds {} numbers for {dims:?}",
                    init.name,
                    data.len()
                )));
            }
            t.insert(init.name.clone(), (dims, data));
        }
        let mut t = Initialisers(t);
        let (cd, ctx_w) = t.take("l_ctx.w", &[None, None])?;
        let (d_global, d) = (cd[0], cd[1]);
        if heads == 0 || d % heads != 0 {
            return Err(bad(format!("{d} wide does not split into {heads} heads")));
        }
        let ctx_b = t.vec("l_ctx.b", d)?;
        let mut table = |name: &str| -> Result<(usize, Vec<f32>), LmError> {
            let (dims, data) = t.take(name, &[None, Some(d)])?;
            Ok((dims[0], data))
        };
        let (r_in, emb_in) = table("l_in")?;
        let (r_vel, emb_vel) = table("l_vel")?;
        let (r_prev, emb_prev) = table("l_prev")?;
        let (r_pos, pos) = table("l_pos")?;
        let mut blocks = Vec::with_capacity(layers);
        for l in 0..layers {
            let n = |w: &str| format!("l{l}.{w}");
            blocks.push(Block {
                ln1: (t.vec(&n("ln1.w"), d)?, t.vec(&n("ln1.b"), d)?),
                qkv: t.linear(&n("qkv"), d, Some(3 * d))?,
                o: t.linear(&n("o"), d, Some(d))?,
                ln2: (t.vec(&n("ln2.w"), d)?, t.vec(&n("ln2.b"), d)?),
                fc1: t.linear(&n("fc1"), d, Some(4 * d))?,
                fc2: t.linear(&n("fc2"), 4 * d, Some(d))?,
            });
        }
        if t.0.contains_key(&format!("l{layers}.qkv.w")) {
            return Err(bad(format!(
                "the graph has more than the manifest's {layers} blocks"
            )));
        }
        let ln = (t.vec("l_ln.w", d)?, t.vec("l_ln.b", d)?);
        let rel = t.linear("rel", d, None)?;
        let abs = t.linear("abs", d, None)?;
        Ok(LocalKernel(Arc::new(Weights {
            d_global,
            d,
            heads,
            eps,
            rows: [r_in, r_vel, r_prev, r_pos],
            ctx: (ctx_w, ctx_b),
            emb_in,
            emb_vel,
            emb_prev,
            pos,
            blocks,
            ln,
            rel,
            abs,
        })))
    }
}

impl Graph for LocalKernel {
    fn spawn(&self) -> Result<Box<dyn GraphState>, LmError> {
        Ok(Box::new(KernelState::new(self.0.clone())))
    }

    fn batches(&self) -> bool {
        true
    }

    fn spawn_batch(&self, _n: usize) -> Result<Option<Box<dyn GraphState>>, LmError> {
        Ok(Some(self.spawn()?))
    }
}

/// A run state: the buffers, and the last global state's projection.
struct KernelState {
    w: Arc<Weights>,
    ctx_seen: Vec<f32>,
    ctx_proj: Vec<f32>,
    x: Vec<f32>,
    a: Vec<f32>,
    qkv: Vec<f32>,
    att: Vec<f32>,
    f: Vec<f32>,
    scores: Vec<f32>,
    live: Vec<usize>,
}

impl KernelState {
    fn new(w: Arc<Weights>) -> KernelState {
        KernelState {
            w,
            ctx_seen: Vec::new(),
            ctx_proj: Vec::new(),
            x: Vec::new(),
            a: Vec::new(),
            qkv: Vec::new(),
            att: Vec::new(),
            f: Vec::new(),
            scores: Vec::new(),
            live: Vec::new(),
        }
    }
}

/// An input's data, checked for its kind and length.
fn f32_in<'a>(
    inputs: &'a [In<'_>],
    i: usize,
    name: &str,
    len: usize,
) -> Result<&'a [f32], LmError> {
    match inputs.get(i) {
        Some(In::F32(_, d)) if d.len() == len => Ok(d),
        _ => Err(bad(format!("input {name} is not {len} floats"))),
    }
}

fn i64_in<'a>(
    inputs: &'a [In<'_>],
    i: usize,
    name: &str,
    len: usize,
) -> Result<&'a [i64], LmError> {
    match inputs.get(i) {
        Some(In::I64(_, d)) if d.len() == len => Ok(d),
        _ => Err(bad(format!("input {name} is not {len} integers"))),
    }
}

/// Row `id` of a `[rows, d]` table, checked.
fn row<'a>(
    table: &'a [f32],
    rows: usize,
    d: usize,
    id: i64,
    name: &str,
) -> Result<&'a [f32], LmError> {
    if id < 0 || id as usize >= rows {
        return Err(bad(format!("{name} id {id} is outside 0..{rows}")));
    }
    let i = id as usize;
    Ok(&table[i * d..(i + 1) * d])
}

impl GraphState for KernelState {
    fn run(
        &mut self,
        inputs: &[In<'_>],
        cache: Option<&Cache>,
        out: &mut Outputs,
    ) -> Result<(), LmError> {
        let w = self.w.clone();
        let (d, h) = (w.d, w.heads);
        let dh = d / h;
        let n = match inputs.get(1) {
            Some(In::I64(_, ids)) => ids.len(),
            _ => return Err(bad("input inp is not integers")),
        };
        let cache = cache.ok_or_else(|| bad("no key/value cache"))?;
        if cache.k.len() != w.blocks.len() || cache.batch != n || cache.heads != h || cache.dh != dh
        {
            return Err(bad(format!(
                "the cache is {} layers of {:?}, the step wants {} of [{n}, {h}, _, {dh}]",
                cache.k.len(),
                cache.shape(),
                w.blocks.len()
            )));
        }
        let cap = cache.cap;
        let ctx = f32_in(inputs, 0, "ctx", n * w.d_global)?;
        let inp = i64_in(inputs, 1, "inp", n)?;
        let vel = i64_in(inputs, 2, "vel", n)?;
        let prev = i64_in(inputs, 3, "prev", n)?;
        let slot = i64_in(inputs, 4, "slot", 1)?[0];
        let bias = f32_in(inputs, 5, "bias", cap + 1)?;
        // The global state's projection: the same for every slot of a frame.
        if self.ctx_seen.as_slice() != ctx {
            self.ctx_seen.clear();
            self.ctx_seen.extend_from_slice(ctx);
            self.ctx_proj.resize(n * d, 0.0);
            gemm(ctx, n, &w.ctx.0, &w.ctx.1, &mut self.ctx_proj);
        }
        let [r_in, r_vel, r_prev, r_pos] = w.rows;
        let pos = row(&w.pos, r_pos, d, slot, "slot")?;
        self.x.resize(n * d, 0.0);
        for b in 0..n {
            let terms = [
                &self.ctx_proj[b * d..(b + 1) * d],
                row(&w.emb_in, r_in, d, inp[b], "inp")?,
                row(&w.emb_vel, r_vel, d, vel[b], "vel")?,
                row(&w.emb_prev, r_prev, d, prev[b], "prev")?,
                pos,
            ];
            for (j, x) in self.x[b * d..(b + 1) * d].iter_mut().enumerate() {
                *x = terms.iter().map(|t| t[j]).sum();
            }
        }
        // The keys that count: the filled cache rows (bias 0); the new
        // position (the bias's last entry) always does.
        let mut live = std::mem::take(&mut self.live);
        live.clear();
        live.extend((0..cap).filter(|&j| bias[j] > -1e8));
        let scale = 1.0 / (dh as f32).sqrt();
        let nout = 2 + 2 * w.blocks.len();
        if out.0.len() != nout {
            out.0.resize_with(nout, Default::default);
        }
        for (l, blk) in w.blocks.iter().enumerate() {
            layer_norm(&self.x, d, &blk.ln1, w.eps, &mut self.a);
            self.qkv.resize(n * 3 * d, 0.0);
            gemm(&self.a, n, &blk.qkv.0, &blk.qkv.1, &mut self.qkv);
            let (kv, vv) = (
                cache.k[l].try_as_plain_ram().map_err(bad)?,
                cache.v[l].try_as_plain_ram().map_err(bad)?,
            );
            let kc = kv.as_slice::<f32>().map_err(bad)?;
            let vc = vv.as_slice::<f32>().map_err(bad)?;
            self.att.resize(n * d, 0.0);
            self.scores.resize(live.len() + 1, 0.0);
            for b in 0..n {
                let qkv = &self.qkv[b * 3 * d..(b + 1) * 3 * d];
                for hh in 0..h {
                    let q = &qkv[hh * dh..(hh + 1) * dh];
                    let kn = &qkv[d + hh * dh..d + (hh + 1) * dh];
                    let vn = &qkv[2 * d + hh * dh..2 * d + (hh + 1) * dh];
                    let base = (b * h + hh) * cap;
                    for (s, &j) in self.scores.iter_mut().zip(&live) {
                        let k = &kc[(base + j) * dh..(base + j + 1) * dh];
                        *s = dot(q, k) * scale + bias[j];
                    }
                    let last = live.len();
                    self.scores[last] = dot(q, kn) * scale + bias[cap];
                    softmax_rows(&mut self.scores, last + 1);
                    let o = &mut self.att[b * d + hh * dh..b * d + (hh + 1) * dh];
                    o.iter_mut().for_each(|v| *v = 0.0);
                    for (&p, &j) in self.scores.iter().zip(&live) {
                        let v = &vc[(base + j) * dh..(base + j + 1) * dh];
                        o.iter_mut().zip(v).for_each(|(o, v)| *o += p * v);
                    }
                    o.iter_mut()
                        .zip(vn)
                        .for_each(|(o, v)| *o += self.scores[last] * v);
                }
            }
            // The new position's keys and values, [n, heads, 1, dh].
            for (j, part) in [1usize, 2].into_iter().enumerate() {
                let (shape, data) = &mut out.0[2 + 2 * l + j];
                shape.clear();
                shape.extend_from_slice(&[n, h, 1, dh]);
                data.clear();
                for b in 0..n {
                    data.extend_from_slice(
                        &self.qkv[b * 3 * d + part * d..b * 3 * d + (part + 1) * d],
                    );
                }
            }
            self.a.resize(n * d, 0.0);
            gemm(&self.att, n, &blk.o.0, &blk.o.1, &mut self.a);
            self.x.iter_mut().zip(&self.a).for_each(|(x, o)| *x += o);
            layer_norm(&self.x, d, &blk.ln2, w.eps, &mut self.a);
            self.f.resize(n * 4 * d, 0.0);
            gemm(&self.a, n, &blk.fc1.0, &blk.fc1.1, &mut self.f);
            self.f.iter_mut().for_each(|v| *v = gelu(*v));
            self.a.resize(n * d, 0.0);
            gemm(&self.f, n, &blk.fc2.0, &blk.fc2.1, &mut self.a);
            self.x.iter_mut().zip(&self.a).for_each(|(x, f)| *x += f);
        }
        self.live = live;
        layer_norm(&self.x, d, &w.ln, w.eps, &mut self.a);
        for (i, head) in [&w.rel, &w.abs].into_iter().enumerate() {
            let m = head.1.len();
            let (shape, data) = &mut out.0[i];
            shape.clear();
            shape.extend_from_slice(&[n, 1, m]);
            data.resize(n * m, 0.0);
            gemm(&self.a, n, &head.0, &head.1, data);
        }
        Ok(())
    }
}

/// The kernel for a local step graph (`bytes`, loaded by its runtime as
/// `graph`), if it reproduces the graph: both run the same four probe
/// slots for two rows side by side (one on a graph without the batch
/// dimension), and every output must agree within [`PROBE_TOLERANCE`].
/// Returns the kernel and the largest difference seen, or the reason it
/// is not used (weights it cannot read, or outputs that differ).
pub fn checked(
    graph: &dyn Graph,
    bytes: &[u8],
    (layers, heads, eps): (usize, usize, f32),
) -> Result<(LocalKernel, f32), String> {
    let kernel = LocalKernel::from_onnx(bytes, layers, heads, eps).map_err(|e| e.to_string())?;
    let w = kernel.0.clone();
    let n = if graph.batches() { 2 } else { 1 };
    let mut ours = kernel.spawn().map_err(|e| e.to_string())?;
    let mut theirs = match graph.spawn_batch(n).map_err(|e| e.to_string())? {
        Some(st) => st,
        None => graph.spawn().map_err(|e| e.to_string())?,
    };
    let cap = w.rows[3];
    let dh = w.d / heads;
    let new_cache = || Cache::batched(n, layers, heads, cap, dh);
    let (mut c_ours, mut c_theirs) = (new_cache(), new_cache());
    let (mut o_ours, mut o_theirs) = (Outputs::default(), Outputs::default());
    // Deterministic, varied inputs within each table's rows.
    let ctx: Vec<f32> = (0..n * w.d_global)
        .map(|i| ((i * 7919 % 1009) as f32 / 504.5 - 1.0) * 1.5)
        .collect();
    let mut worst = 0f32;
    for s in 0..4.min(cap) {
        let pick = |rows: usize, salt: usize| -> Vec<i64> {
            (0..n)
                .map(|b| ((s * 31 + b * 17 + salt) % rows) as i64)
                .collect()
        };
        let (inp, vel, prev) = (pick(w.rows[0], 3), pick(w.rows[1], 11), pick(w.rows[2], 5));
        let slot = [s as i64];
        for (st, cache, out) in [
            (&mut ours, &mut c_ours, &mut o_ours),
            (&mut theirs, &mut c_theirs, &mut o_theirs),
        ] {
            let bias = cache.bias().to_vec();
            let inputs = [
                In::F32(&[n, w.d_global], &ctx),
                In::I64(&[n], &inp),
                In::I64(&[n], &vel),
                In::I64(&[n], &prev),
                In::I64(&[1], &slot),
                In::F32(&[1, bias.len()], &bias),
            ];
            st.run(&inputs, Some(cache), out)
                .map_err(|e| e.to_string())?;
            cache.push(out, 2).map_err(|e| e.to_string())?;
        }
        if o_ours.0.len() != o_theirs.0.len() {
            return Err(format!(
                "the graph gives {} outputs, the kernel {}",
                o_theirs.0.len(),
                o_ours.0.len()
            ));
        }
        for (i, ((_, a), (_, b))) in o_ours.0.iter().zip(&o_theirs.0).enumerate() {
            if a.len() != b.len() {
                return Err(format!(
                    "output {i}: {} numbers against the graph's {}",
                    a.len(),
                    b.len()
                ));
            }
            // NaN-propagating: a NaN anywhere fails the probe.
            let diff = a
                .iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0f32, |m, d| if d.is_nan() || d > m { d } else { m });
            if diff.is_nan() || diff > PROBE_TOLERANCE {
                return Err(format!(
                    "output {i} at slot {s} lies {diff:e} from the graph's (tolerance {PROBE_TOLERANCE:e})"
                ));
            }
            worst = worst.max(diff);
        }
    }
    Ok((kernel, worst))
}
