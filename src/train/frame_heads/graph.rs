//! Writing fitted heads into a frame model's global graph, and the copy
//! of the model folder that carries them (checked by reloading it).

use super::{change_magnitude, Features, HeadWindow, Linear};
use crate::lm::frame_runtime::FrameSession;
use anyhow::{bail, Context, Result};
use prost::Message;
use std::path::Path;

/// Sets an initialiser's data, checking its shape.
fn set_init(
    graph: &mut tract_onnx::pb::GraphProto,
    name: &str,
    dims: &[i64],
    data: &[f32],
) -> Result<()> {
    let init = graph
        .initializer
        .iter_mut()
        .find(|t| t.name == name)
        .with_context(|| format!("the global graph has no initialiser {name}"))?;
    if init.dims != dims {
        bail!(
            "{name}: the graph's shape {:?}, the fit's {:?}",
            init.dims,
            dims
        );
    }
    init.float_data.clear();
    init.raw_data = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    Ok(())
}

/// Writes the fitted heads into the global graph's bytes. Every head's
/// state path becomes `(h − cls.{kind}.ch) · cls.{kind}.w + cls.{kind}.b`
/// (a `Sub` before the head's `MatMul`). A head on the state and the pose
/// statistics (`d_global + 3 · slots` features) also gets a pose path: the
/// state path's sum is renamed `cls_{kind}_state`, and `cls_{kind}` adds
/// `(v − cv) · wv + (v² − cv2) · wv2 + (m − cm) · wm` (all `cls.{kind}.*`),
/// with `v = val / bins` and `m` the change code's magnitude over `bins` (a
/// table lookup on `chg`): the per-step terms of [`pose_stats`](super::pose_stats). A graph
/// that already has these paths only gets new weights; a state-only head
/// cannot replace a pose path.
pub fn rewrite_heads(
    onnx: &[u8],
    cfg: &crate::lm::frame::FrameConfig,
    heads: &[Option<Linear>],
) -> Result<Vec<u8>> {
    use crate::train::export::{attr_i, Builder, DataType};
    let (d, slots) = (cfg.d_global, cfg.slots);
    let mut proto =
        tract_onnx::pb::ModelProto::decode(onnx).context("the global graph is not ONNX")?;
    let graph = proto
        .graph
        .as_mut()
        .context("the global graph has no graph")?;
    let has = |g: &tract_onnx::pb::GraphProto, n: &str| g.initializer.iter().any(|t| t.name == n);
    let mut tail = Builder::default();
    let mut shared = false;
    for ((kind, values), head) in cfg.classes.iter().zip(heads) {
        let Some(h) = head else { continue };
        let nc = values.len();
        let width = h.weights.first().map_or(0, |w| w.len());
        let pose = match width {
            w if w == d => false,
            w if w == d + 3 * slots => true,
            w => bail!(
                "{kind}: a head of {w} features fits neither the state ({d}) nor the state and pose ({})",
                d + 3 * slots
            ),
        };
        let name = |n: &str| format!("cls.{kind}.{n}");
        if !pose && has(graph, &name("wv")) {
            bail!("{kind}: the graph has a pose path; a state-only head cannot replace it");
        }
        // Rows = features (from `from`, every `step`-th), columns = classes.
        let block = |from: usize, rows: usize, step: usize| -> Vec<f32> {
            let mut out = vec![0f32; rows * nc];
            for (c, row) in h.weights.iter().enumerate() {
                for r in 0..rows {
                    out[r * nc + c] = row[from + r * step] as f32;
                }
            }
            out
        };
        let centre = |from: usize, rows: usize, step: usize| -> Vec<f32> {
            (0..rows)
                .map(|r| h.centre.get(from + r * step).copied().unwrap_or(0.0) as f32)
                .collect()
        };
        let b: Vec<f32> = h.bias.iter().map(|&v| v as f32).collect();
        set_init(graph, &name("w"), &[d as i64, nc as i64], &block(0, d, 1))?;
        set_init(graph, &name("b"), &[nc as i64], &b)?;
        if has(graph, &name("ch")) {
            set_init(graph, &name("ch"), &[d as i64], &centre(0, d, 1))?;
        } else {
            // Centre the state before the head's product.
            let w = name("w");
            let at = graph
                .node
                .iter()
                .position(|n| n.op_type == "MatMul" && n.input.iter().any(|i| *i == w))
                .with_context(|| format!("the global graph has no MatMul reading {w}"))?;
            let x = graph.node[at]
                .input
                .iter()
                .find(|i| **i != w)
                .cloned()
                .context("the head's MatMul has one input")?;
            let mut pre = Builder::default();
            pre.f32(&name("ch"), &[d], centre(0, d, 1));
            let hc = format!("cls_{kind}_centred");
            pre.op("Sub", &[&x, &name("ch")], vec![], Some(&hc));
            graph.node[at]
                .input
                .iter_mut()
                .filter(|i| **i == x)
                .for_each(|i| *i = hc.clone());
            let mut sub = pre.nodes.pop().expect("one node");
            sub.name = format!("cls_{kind}_centre_Sub");
            graph.node.insert(at, sub);
            graph.initializer.extend(pre.inits);
        }
        if !pose {
            continue;
        }
        let ws = ["wv", "wv2", "wm"].map(name);
        let cs = ["cv", "cv2", "cm"].map(name);
        let wblocks = [
            block(d, slots, 3),
            block(d + 1, slots, 3),
            block(d + 2, slots, 3),
        ];
        let cblocks = [
            centre(d, slots, 3),
            centre(d + 1, slots, 3),
            centre(d + 2, slots, 3),
        ];
        if has(graph, &ws[0]) {
            for (n, w) in ws.iter().zip(&wblocks) {
                set_init(graph, n, &[slots as i64, nc as i64], w)?;
            }
            for (n, c) in cs.iter().zip(&cblocks) {
                set_init(graph, n, &[slots as i64], c)?;
            }
            continue;
        }
        let out = format!("cls_{kind}");
        let state = format!("cls_{kind}_state");
        let node = graph
            .node
            .iter_mut()
            .find(|n| n.output.iter().any(|o| *o == out))
            .with_context(|| format!("the global graph has no node giving {out}"))?;
        node.output
            .iter_mut()
            .filter(|o| **o == out)
            .for_each(|o| *o = state.clone());
        let g = &mut tail;
        if !shared {
            shared = true;
            let mags: Vec<f32> = (0..cfg.change_rows() as u32)
                .map(|c| (change_magnitude(cfg, c) / cfg.bins as f64) as f32)
                .collect();
            g.f32("pose_mag_table", &[mags.len()], mags);
            g.scalar("pose_inv_bins", 1.0 / cfg.bins as f32);
            let vf = g.op(
                "Cast",
                &["val"],
                vec![attr_i("to", DataType::Float as i64)],
                Some("pose_val_f"),
            );
            g.op("Mul", &[&vf, "pose_inv_bins"], vec![], Some("pose_v"));
            g.op("Mul", &["pose_v", "pose_v"], vec![], Some("pose_v2"));
            g.op(
                "Gather",
                &["pose_mag_table", "chg"],
                vec![attr_i("axis", 0)],
                Some("pose_m"),
            );
        }
        let mut sum = state.clone();
        for (i, (src, part)) in [("pose_v", "v"), ("pose_v2", "v2"), ("pose_m", "m")]
            .into_iter()
            .enumerate()
        {
            g.f32(&ws[i], &[slots, nc], wblocks[i].clone());
            g.f32(&cs[i], &[slots], cblocks[i].clone());
            let c = g.op(
                "Sub",
                &[src, &cs[i]],
                vec![],
                Some(&format!("pose_{kind}_{part}_c")),
            );
            let t = g.op(
                "MatMul",
                &[&c, &ws[i]],
                vec![],
                Some(&format!("pose_{kind}_{part}")),
            );
            let o = if i == 2 {
                out.clone()
            } else {
                format!("pose_{kind}_{part}_sum")
            };
            sum = g.op("Add", &[&sum, &t], vec![], Some(&o));
        }
    }
    for (i, mut n) in tail.nodes.into_iter().enumerate() {
        n.name = format!("pose_{i}_{}", n.op_type);
        graph.node.push(n);
    }
    graph.initializer.extend(tail.inits);
    Ok(proto.encode_to_vec())
}

/// Copies a frame model folder to `out` with the fitted heads written into
/// its global graph, the manifest's hash updated and the report kept in its
/// training record; then loads the copy and checks that its `classify`
/// agrees with the fitted discriminants on `check` windows.
pub fn write_model(
    model: &Path,
    out: &Path,
    heads: &[Option<Linear>],
    report: &serde_json::Value,
    check: &[HeadWindow],
    features: Features,
    engine: &crate::lm::engine::Engine,
) -> Result<()> {
    use crate::lm::frame::FrameManifest;
    let (mut m, global, _) = FrameManifest::load(model)?;
    std::fs::create_dir_all(out)?;
    for e in std::fs::read_dir(model)? {
        let e = e?;
        if e.file_type()?.is_file() {
            std::fs::copy(e.path(), out.join(e.file_name()))?;
        }
    }
    let bytes = rewrite_heads(&global, &m.config, heads)?;
    std::fs::write(out.join(&m.global_onnx), &bytes)?;
    m.global_sha256 = crate::lm::manifest::sha256_hex(&bytes);
    if let serde_json::Value::Object(t) = &mut m.training {
        t.insert("class_heads".into(), report.clone());
    }
    for (k, acc, n) in report["kinds"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|r| {
            Some((
                r["kind"].as_str()?.to_string(),
                r["new_head"].as_f64()?,
                r["held_out_windows"].as_f64()?,
            ))
        })
    {
        m.metrics.insert(format!("val_accuracy_{k}"), acc);
        m.metrics.insert(format!("val_windows_{k}"), n);
    }
    std::fs::write(out.join("manifest.json"), serde_json::to_vec_pretty(&m)?)?;
    let s = FrameSession::load_with(out, engine)?;
    for w in check {
        let (values, state) = (&w.values, &features.of(w));
        let logits = s.classify(values)?;
        for ((l, h), (k, _)) in logits.iter().zip(heads).zip(&m.config.classes) {
            let Some(h) = h else { continue };
            for (c, want) in h.scores(state).into_iter().enumerate() {
                let got = l[c] as f64;
                if (want - got).abs() > 1e-3 * (1.0 + want.abs()) {
                    bail!("{k} class {c}: the written graph gives {got}, the fit {want}");
                }
            }
        }
    }
    Ok(())
}

/// Writes into `dir` a copy of the exported frame model `model` whose
/// global graph has one class-head slot per kind in `classify` (values
/// from the vocabulary), every other weight read back from the model's own
/// graphs and written again unchanged, and checks that the copy answers
/// as those weights do. The slots start untrained: `fit-heads` fits them.
/// Files beside the graphs (style exemplars) are copied. Returns false
/// (and writes nothing) when `classify` is empty or names exactly the
/// heads the model has.
pub fn add_head_slots(
    model: &Path,
    classify: &[String],
    dir: &Path,
    engine: &crate::lm::engine::Engine,
) -> Result<bool> {
    use crate::lm::frame::FrameManifest;
    use crate::train::frame;
    if classify.is_empty() {
        return Ok(false);
    }
    let (_, _, m): (_, _, FrameManifest) = crate::lm::manifest::read_manifest(model)?;
    let have: Vec<&String> = m.config.classes.iter().map(|(k, _)| k).collect();
    if have.len() == classify.len() && classify.iter().all(|k| have.contains(&k)) {
        return Ok(false);
    }
    let dev = crate::train::device();
    let classes =
        crate::train::flat_run::class_values(&m.vocabulary, classify).context("--classify")?;
    let (m, vocab, net) = frame::net_from_export(model, classes, &dev)?;
    crate::train::frame_export::export(&net, &vocab, m.data, m.metrics, m.training, dir)?;
    for e in std::fs::read_dir(model)? {
        let e = e?;
        if e.path().is_file() && !dir.join(e.file_name()).exists() {
            std::fs::copy(e.path(), dir.join(e.file_name()))?;
        }
    }
    let values: Vec<u32> = (0..8 * net.cfg.slots)
        .map(|i| (i % vocab.bins) as u32)
        .collect();
    let (worst, scale) = crate::train::frame_export::parity(
        &net,
        &vocab,
        dir,
        &values,
        &Default::default(),
        engine,
    )?;
    if !(worst <= 1e-3 * scale.max(1.0)) {
        bail!(
            "{}: the copy with head slots answers {worst:.1e} off the weights it was written from",
            model.display()
        );
    }
    Ok(true)
}
