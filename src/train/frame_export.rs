//! ONNX export of the frame model as two step graphs with static shapes:
//! the global step (one frame, or the conditioning, per call) and the
//! local step (one slot per call). Both take fixed-capacity key/value
//! caches whose unused rows the `bias` input masks, and return only the new
//! position's keys and values; the runtime writes them into its caches in
//! place.

use super::export::{attr_i, attr_ints, value_info, Builder, DataType};
use super::frame::FrameNet;
use crate::lm::frame::{
    global_inputs, global_outputs, local_inputs, local_outputs, FrameConfig, FrameManifest,
    FRAME_KIND, GLOBAL_ONNX, LOCAL_BATCH, LOCAL_ONNX,
};
use crate::lm::manifest::{sha256_hex, DataInfo, MANIFEST_FORMAT};
use crate::tokenize::vocab::Vocabulary;
use prost::Message;
use std::collections::BTreeMap;
use std::path::Path;
use tract_onnx::pb::ModelProto;

fn gather(g: &mut Builder, table: &str, ids: &str) -> String {
    g.op("Gather", &[table, ids], vec![attr_i("axis", 0)], None)
}

/// A stack of pre-LN transformer blocks `{pre}0..layers` of width `d`.
struct Blocks<'a> {
    pre: &'a str,
    layers: usize,
    d: usize,
    heads: usize,
    eps: f32,
}

/// Layer `l`'s cached keys and values with the new position's `k`, `v`
/// appended (`cache_k_{l}`, `cache_v_{l}` along the positions axis).
fn with_cache(g: &mut Builder, l: usize, k: &str, v: &str) -> (String, String) {
    let mut cat = |which: &str, new: &str| {
        g.op(
            "Concat",
            &[&format!("cache_{which}_{l}"), new],
            vec![attr_i("axis", 2)],
            None,
        )
    };
    let kc = cat("k", k);
    (kc, cat("v", v))
}

/// Pre-LN blocks `{pre}{l}` over `x: [1, 1, d]` with cached keys/values
/// (`cache_k_{l}` `[1, H, C, dh]`) and the `bias` input; names the new
/// keys/values `k_{l}`, `v_{l}`. The global step's form: it runs once or
/// twice a frame, so its operation count matters less than the local
/// step's (once a slot, [`row_blocks`]), and `fit-heads` edits its head
/// nodes as written here.
fn cached_blocks(g: &mut Builder, x: &str, b: &Blocks) -> String {
    let (pre, layers, eps) = (b.pre, b.layers, b.eps);
    let (d, h, dh) = (b.d as i64, b.heads as i64, (b.d / b.heads) as i64);
    let mut x = x.to_string();
    for l in 0..layers {
        let n = |s: &str| format!("{pre}{l}.{s}");
        let (q, k, v) = g.qkv(&x, &n, eps, h, dh);
        let kn = g.op("Identity", &[&k], vec![], Some(&format!("k_{l}")));
        let vn = g.op("Identity", &[&v], vec![], Some(&format!("v_{l}")));
        let (kc, vc) = with_cache(g, l, &kn, &vn);
        let att = g.attend(&q, &kc, &vc, Some("bias"), d, dh);
        let o = g.lin(&att, &n("o"));
        x = g.op("Add", &[&x, &o], vec![], None);
        x = g.mlp_residual(&x, &n, eps);
    }
    x
}

/// A block's query, key and value weights as one linear layer in a graph:
/// `{block}.qkv.w` (`[d, 3d]`, the three side by side) and `.b`.
const QKV: &str = "qkv";

/// Fuses the query/key/value weights of the blocks `{pre}0..layers` in
/// `w` into one layer each (the form [`row_blocks`] reads).
fn fuse_qkv(
    w: &mut BTreeMap<String, candle_core::Tensor>,
    pre: &str,
    layers: usize,
) -> anyhow::Result<()> {
    for l in 0..layers {
        for (part, dim) in [("w", 1), ("b", 0)] {
            let mut three = Vec::with_capacity(3);
            for p in ["q", "k", "v"] {
                let name = format!("{pre}{l}.{p}.{part}");
                three.push(
                    w.remove(&name)
                        .ok_or_else(|| anyhow::anyhow!("no weight {name} to export"))?,
                );
            }
            w.insert(
                format!("{pre}{l}.{QKV}.{part}"),
                candle_core::Tensor::cat(&three, dim)?,
            );
        }
    }
    Ok(())
}

/// The float weights of an exported frame graph by the trainer's names:
/// its initialisers, each fused query/key/value layer split back into
/// `q`, `k`, `v` (exactly: the fused layer is the three side by side).
pub fn graph_weights(
    path: &Path,
    dev: &candle_core::Device,
) -> anyhow::Result<BTreeMap<String, candle_core::Tensor>> {
    let mut t = super::export::float_initializers(path, dev)?;
    let fused: Vec<String> = t
        .keys()
        .filter(|k| k.ends_with(&format!(".{QKV}.w")) || k.ends_with(&format!(".{QKV}.b")))
        .cloned()
        .collect();
    for name in fused {
        let x = t.remove(&name).expect("listed");
        let (block, part) = name
            .rsplit_once(&format!(".{QKV}."))
            .expect("listed by its suffix");
        let dim = if part == "w" { 1 } else { 0 };
        let n = x.dim(dim)?;
        if n % 3 != 0 {
            anyhow::bail!("{}: {name} is {n} wide, not three layers", path.display());
        }
        for (i, p) in ["q", "k", "v"].iter().enumerate() {
            t.insert(
                format!("{block}.{p}.{part}"),
                x.narrow(dim, i * n / 3, n / 3)?.contiguous()?,
            );
        }
    }
    Ok(t)
}

/// Pre-LN blocks `{pre}{l}` over one position per row, `x: [B, d]` (a
/// step: every row at the same position, e.g. candidate frames at one
/// slot), with cached keys/values (`cache_k_{l}` `[B, H, C, dh]`) and the
/// `bias` input (`[1, C + 1]`); the new keys/values are the outputs `k_{l}`,
/// `v_{l}` (`[B, H, 1, dh]`). Written for a runtime that pays for every
/// operation it runs (onnxruntime's cost at this size is mostly per
/// node): each linear layer is one `Gemm` over the rows, the query, key
/// and value one product (weights fused by [`fuse_qkv`]) cut into heads by
/// a reshape and a split.
fn row_blocks(g: &mut Builder, x: &str, b: &Blocks) -> String {
    let (pre, layers, eps) = (b.pre, b.layers, b.eps);
    let (d, h, dh) = (b.d as i64, b.heads as i64, (b.d / b.heads) as i64);
    let qkv_shape = g.i64("shape_qkv", &[0, 3 * h, 1, dh]);
    let split = g.i64("split_qkv", &[h, h, h]);
    let row = g.i64("shape_row", &[0, d]);
    let scale = g.scalar("attn_scale", 1.0 / (dh as f32).sqrt());
    let mut x = x.to_string();
    for l in 0..layers {
        let n = |s: &str| format!("{pre}{l}.{s}");
        let a = g.ln(&x, &n("ln1"), eps);
        let qkv = g.gemm(&a, &n(QKV));
        let qkv = g.op("Reshape", &[&qkv, &qkv_shape], vec![], None);
        let (q, k, v) = (n("q_heads"), format!("k_{l}"), format!("v_{l}"));
        g.ops(
            "Split",
            &[&qkv, &split],
            vec![attr_i("axis", 1)],
            &[&q, &k, &v],
        );
        let (kc, vc) = with_cache(g, l, &k, &v);
        let kt = g.op(
            "Transpose",
            &[&kc],
            vec![attr_ints("perm", &[0, 1, 3, 2])],
            None,
        );
        let s = g.op("MatMul", &[&q, &kt], vec![], None);
        let s = g.op("Mul", &[&s, &scale], vec![], None);
        let s = g.op("Add", &[&s, "bias"], vec![], None);
        let p = g.op("Softmax", &[&s], vec![attr_i("axis", -1)], None);
        let att = g.op("MatMul", &[&p, &vc], vec![], None);
        // [B, H, 1, dh] is already the heads side by side in a row.
        let att = g.op("Reshape", &[&att, &row], vec![], None);
        let o = g.gemm(&att, &n("o"));
        x = g.op("Add", &[&x, &o], vec![], None);
        let m = g.ln(&x, &n("ln2"), eps);
        let f = g.gemm(&m, &n("fc1"));
        let f = g.gelu(&f);
        let f = g.gemm(&f, &n("fc2"));
        x = g.op("Add", &[&x, &f], vec![], None);
    }
    x
}

/// Key/value inputs (`[batch, H, cap, dh]`) or outputs (`[batch, H, 1,
/// dh]`); `batch` a number or a symbol.
fn kv_info(
    names: &[String],
    batch: &str,
    heads: usize,
    cap: usize,
    dh: usize,
    out: bool,
) -> Vec<tract_onnx::pb::ValueInfoProto> {
    let len = if out { 1 } else { cap };
    names
        .iter()
        .map(|n| {
            value_info(
                n,
                DataType::Float,
                &[batch, &heads.to_string(), &len.to_string(), &dh.to_string()],
            )
        })
        .collect()
}

/// The global step graph.
pub fn global_model(net: &FrameNet) -> anyhow::Result<ModelProto> {
    let c = &net.cfg;
    let mut g = Builder::default();
    let mut w = BTreeMap::new();
    for (k, v) in net.params.tensors() {
        if k.starts_with("g") || k.starts_with("cls.") {
            w.insert(k, v);
        }
    }
    g.weights(w)?;
    let eps = c.ln_eps as f32;
    let dg = c.d_global as i64;
    let ev = gather(&mut g, "g_val", "val");
    let ec = gather(&mut g, "g_chg", "chg");
    let e = g.op("Add", &[&ev, &ec], vec![], None);
    let flat = g.i64("shape_frame", &[1, 1, (c.slots * c.d_emb) as i64]);
    let e = g.op("Reshape", &[&e, &flat], vec![], None);
    let mut frame = g.lin(&e, "g_in");
    if c.cond_every {
        let every = g.op("MatMul", &["cond", "g_cond_all"], vec![], None);
        let one_d = g.i64("shape_every", &[1, 1, dg]);
        let every = g.op("Reshape", &[&every, &one_d], vec![], None);
        frame = g.op("Add", &[&frame, &every], vec![], None);
    }
    let cv = g.op("MatMul", &["cond", "g_cond"], vec![], None);
    let one_d = g.i64("shape_one", &[1, 1, dg]);
    let cv = g.op("Reshape", &[&cv, &one_d], vec![], None);
    let one = g.scalar("one", 1.0);
    let not_cond = g.op("Sub", &[&one, "is_cond"], vec![], None);
    let a = g.op("Mul", &[&frame, &not_cond], vec![], None);
    let b = g.op("Mul", &[&cv, "is_cond"], vec![], None);
    let x = g.op("Add", &[&a, &b], vec![], None);
    let p = gather(&mut g, "g_pos", "pos");
    let x = g.op("Add", &[&x, &p], vec![], None);
    let x = cached_blocks(
        &mut g,
        &x,
        &Blocks {
            pre: "g",
            layers: c.global_layers,
            d: c.d_global,
            heads: c.global_heads,
            eps,
        },
    );
    let h = g.ln(&x, "g_ln", eps);
    g.op("Identity", &[&h], vec![], Some("h"));
    for (k, _) in &c.classes {
        let m = g.op("MatMul", &[&h, &format!("cls.{k}.w")], vec![], None);
        g.op(
            "Add",
            &[&m, &format!("cls.{k}.b")],
            vec![],
            Some(&format!("cls_{k}")),
        );
    }
    let cap = c.max_frames + 1;
    let dh = c.d_global / c.global_heads;
    let names = global_inputs(c);
    let s = c.slots.to_string();
    let mut inputs = vec![
        value_info("val", DataType::Int64, &["1", &s]),
        value_info("chg", DataType::Int64, &["1", &s]),
        value_info("cond", DataType::Float, &["1", &c.vocab_size.to_string()]),
        value_info("is_cond", DataType::Float, &["1", "1"]),
        value_info("pos", DataType::Int64, &["1"]),
        value_info("bias", DataType::Float, &["1", &(cap + 1).to_string()]),
    ];
    inputs.extend(kv_info(&names[6..], "1", c.global_heads, cap, dh, false));
    let outs = global_outputs(c);
    let mut outputs = vec![value_info(
        "h",
        DataType::Float,
        &["1", "1", &c.d_global.to_string()],
    )];
    for (k, v) in &c.classes {
        outputs.push(value_info(
            &format!("cls_{k}"),
            DataType::Float,
            &["1", "1", &v.len().to_string()],
        ));
    }
    outputs.extend(kv_info(
        &outs[1 + c.classes.len()..],
        "1",
        c.global_heads,
        cap,
        dh,
        true,
    ));
    Ok(g.model("choreo_frame_global", inputs, outputs))
}

/// The local step graph: the rows of `batch` candidate frames at one
/// slot, in [`row_blocks`]' form.
pub fn local_model(net: &FrameNet) -> anyhow::Result<ModelProto> {
    let c = &net.cfg;
    let mut g = Builder::default();
    let mut w = BTreeMap::new();
    for (k, v) in net.params.tensors() {
        if k.starts_with("l") || k.starts_with("rel.") || k.starts_with("abs.") {
            w.insert(k, v);
        }
    }
    fuse_qkv(&mut w, "l", c.local_layers)?;
    g.weights(w)?;
    let eps = c.ln_eps as f32;
    let mut terms = vec![g.gemm("ctx", "l_ctx")];
    for (table, ids) in [
        ("l_in", "inp"),
        ("l_vel", "vel"),
        ("l_prev", "prev"),
        ("l_pos", "slot"),
    ] {
        terms.push(gather(&mut g, table, ids));
    }
    let terms: Vec<&str> = terms.iter().map(String::as_str).collect();
    let x = g.op("Sum", &terms, vec![], None);
    let x = row_blocks(
        &mut g,
        &x,
        &Blocks {
            pre: "l",
            layers: c.local_layers,
            d: c.d_local,
            heads: c.local_heads,
            eps,
        },
    );
    let x = g.ln(&x, "l_ln", eps);
    let one_row = g.i64("shape_out", &[0, 1, -1]);
    for head in ["rel", "abs"] {
        let y = g.gemm(&x, head);
        g.op("Reshape", &[&y, &one_row], vec![], Some(head));
    }
    let cap = c.slots;
    let dh = c.d_local / c.local_heads;
    let names = local_inputs(c);
    // The batch (candidate frames decoded side by side, `sampling.draws`)
    // is a symbol; the slot and the mask are shared by the batch.
    let b = LOCAL_BATCH;
    let mut inputs = vec![
        value_info("ctx", DataType::Float, &[b, &c.d_global.to_string()]),
        value_info("inp", DataType::Int64, &[b]),
        value_info("vel", DataType::Int64, &[b]),
        value_info("prev", DataType::Int64, &[b]),
        value_info("slot", DataType::Int64, &["1"]),
        value_info("bias", DataType::Float, &["1", &(cap + 1).to_string()]),
    ];
    inputs.extend(kv_info(&names[6..], b, c.local_heads, cap, dh, false));
    let outs = local_outputs(c);
    let mut outputs = vec![
        value_info(
            "rel",
            DataType::Float,
            &[b, "1", &c.rel_classes().to_string()],
        ),
        value_info("abs", DataType::Float, &[b, "1", &c.bins.to_string()]),
    ];
    outputs.extend(kv_info(&outs[2..], b, c.local_heads, cap, dh, true));
    Ok(g.model("choreo_frame_local", inputs, outputs))
}

/// Writes both graphs and the manifest into `dir`; returns the manifest.
pub fn export(
    net: &FrameNet,
    vocabulary: &Vocabulary,
    data: DataInfo,
    metrics: BTreeMap<String, f64>,
    training: serde_json::Value,
    dir: &Path,
) -> anyhow::Result<FrameManifest> {
    std::fs::create_dir_all(dir)?;
    let gb = global_model(net)?.encode_to_vec();
    let lb = local_model(net)?.encode_to_vec();
    std::fs::write(dir.join(GLOBAL_ONNX), &gb)?;
    std::fs::write(dir.join(LOCAL_ONNX), &lb)?;
    let m = FrameManifest {
        format: MANIFEST_FORMAT,
        kind: FRAME_KIND.into(),
        config: FrameConfig::clone(&net.cfg),
        vocabulary: vocabulary.clone(),
        global_onnx: GLOBAL_ONNX.into(),
        global_sha256: sha256_hex(&gb),
        local_onnx: LOCAL_ONNX.into(),
        local_sha256: sha256_hex(&lb),
        data,
        metrics,
        training,
        max_jump_by_kind: Default::default(),
        sampling_by_kind: Default::default(),
    };
    m.save(dir)?;
    Ok(m)
}

/// Max |tract − candle| over the change and absolute logits of a window
/// from a sequence's start (`values`: `frames × slots` value tokens),
/// conditioned on `labels`; and the largest |logit| for scale.
pub fn parity(
    net: &FrameNet,
    vocab: &Vocabulary,
    dir: &Path,
    values: &[u32],
    labels: &crate::motion::Labels,
    engine: &crate::lm::engine::Engine,
) -> anyhow::Result<(f32, f32)> {
    use super::frame::{batch, example};
    let c = &net.cfg;
    let dev = super::device();
    let n = (values.len() / c.slots).min(c.max_frames);
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(0);
    let ex = example(c, vocab, values, 0, n, labels, false, 1.0, &mut rng);
    let b = batch(c, &[ex], &dev)?;
    let h = net.global(&b.val, &b.chg, &b.cond)?;
    let ctx = h.narrow(1, 0, n)?.reshape((n, c.d_global))?;
    let (rel, abs) = net.local(&ctx, &b.inp, &b.vel, &b.prev)?;
    let rel = rel.flatten_all()?.to_vec1::<f32>()?;
    let abs = abs.flatten_all()?.to_vec1::<f32>()?;
    let session = crate::lm::frame_runtime::FrameSession::load_with(dir, engine)?;
    let cond = session.cond(labels)?;
    let frames: Vec<Vec<u32>> = values[..n * c.slots]
        .chunks_exact(c.slots)
        .map(|f| f.to_vec())
        .collect();
    let got = session.teacher_forced(&cond, &frames)?;
    let (mut worst, mut scale) = (0f32, 0f32);
    // The batched local graph (candidate frames side by side) against the
    // one-at-a-time runs: three frames of the window as candidates after
    // its first two, under the state after its conditioning.
    if n >= 5 {
        let g = session.state_after(&cond, &frames[..2])?;
        let cands = frames[2..5].to_vec();
        let ctx = (Some(frames[1].as_slice()), Some(frames[0].as_slice()));
        let one = session.local_logits(&g, ctx, &cands, false)?;
        let side = session.local_logits(&g, ctx, &cands, true)?;
        for ((r1, a1), (r2, a2)) in one.iter().zip(&side) {
            for (x, y) in r1.iter().chain(a1).zip(r2.iter().chain(a2)) {
                worst = worst.max((x - y).abs());
            }
        }
    }
    let (nr, na) = (c.slots * c.rel_classes(), c.slots * c.bins);
    for (f, (r, a)) in got.iter().enumerate() {
        for (x, y) in r.iter().zip(&rel[f * nr..(f + 1) * nr]) {
            worst = worst.max((x - y).abs());
            scale = scale.max(y.abs());
        }
        for (x, y) in a.iter().zip(&abs[f * na..(f + 1) * na]) {
            worst = worst.max((x - y).abs());
            scale = scale.max(y.abs());
        }
    }
    Ok((worst, scale))
}

/// Rewrites an exported frame model's local graph (in `dir`) as this
/// exporter writes it, its weights read back unchanged, and its hash in
/// `manifest.json` (every other field kept as written): an export from
/// before the batch dimension then decodes `sampling.draws` candidates
/// side by side, and one from before [`row_blocks`] runs fewer operations
/// a step. Checks the new graph against the old one on a probe (a
/// state after two frames, three candidate frames), one at a time and
/// batched; returns the two largest differences of the logits. A graph
/// already as the exporter writes it is left alone (None).
pub fn upgrade_local(dir: &Path) -> anyhow::Result<Option<(f32, f32)>> {
    use crate::lm::frame_runtime::FrameSession;
    use crate::lm::manifest::{read_manifest, read_onnx_checked};
    let (file, name, m): (_, _, FrameManifest) = read_manifest(dir)?;
    if m.kind != FRAME_KIND {
        anyhow::bail!("{name}: field `kind`: {:?}, want {FRAME_KIND:?}", m.kind);
    }
    let (path, current) = read_onnx_checked(&file, &name, &m.local_onnx, &m.local_sha256)?;
    let old = FrameSession::load(dir)?;
    let dev = super::device();
    let net = FrameNet::new(m.config.clone(), &dev)?;
    let t = graph_weights(&path, &dev)?;
    let missing = net.params.load_matching(&t, &path.display().to_string())?;
    if let Some(n) = missing
        .iter()
        .find(|n| n.starts_with('l') || n.starts_with("rel.") || n.starts_with("abs."))
    {
        anyhow::bail!("{}: the local graph lacks the weight {n}", path.display());
    }
    // A probe: smooth frames round mid-range, every slot its own phase.
    let c = &m.config;
    let frames: Vec<Vec<u32>> = (0..5)
        .map(|f| {
            (0..c.slots)
                .map(|s| {
                    let x = (0.3 * f as f64 + s as f64).sin() * 6.0;
                    (c.bins as f64 / 2.0 + x).round() as u32
                })
                .collect()
        })
        .collect();
    let cond = old.cond(&crate::motion::Labels::new())?;
    let probe = |s: &FrameSession, batched: bool| -> anyhow::Result<Vec<f32>> {
        let h = s.state_after(&cond, &frames[..2])?;
        let ctx = (Some(frames[1].as_slice()), Some(frames[0].as_slice()));
        let out = s.local_logits(&h, ctx, &frames[2..5], batched)?;
        Ok(out
            .into_iter()
            .flat_map(|(r, a)| r.into_iter().chain(a))
            .collect())
    };
    let bytes = local_model(&net)?.encode_to_vec();
    if bytes == current {
        return Ok(None);
    }
    let before = probe(&old, false)?;
    // The manifest's text changes in the one hash (its other fields, and
    // their order and layout, stay as written).
    let text = std::fs::read_to_string(&file)?;
    let quoted = format!("\"{}\"", m.local_sha256);
    if text.matches(&quoted).count() != 1 {
        anyhow::bail!("{name}: the local graph's hash is not written once");
    }
    let text = text.replace(&quoted, &format!("\"{}\"", sha256_hex(&bytes)));
    let tmp = path.with_extension("onnx.new");
    std::fs::write(&tmp, &bytes)?;
    std::fs::rename(&tmp, &path)?;
    std::fs::write(&file, text)?;
    let new = FrameSession::load(dir)?;
    let worst = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max)
    };
    let (one, side) = (probe(&new, false)?, probe(&new, true)?);
    Ok(Some((worst(&before, &one), worst(&before, &side))))
}
