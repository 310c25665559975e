//! Where a frame-model run starts from, and what it records about it: a
//! checkpoint folder or an exported model folder read back into trainer
//! weights, and the lineage (parent steps, time, data, licences) a child
//! run carries into its manifest.

use super::frame::{FrameNet, FrameState};
use crate::lm::frame::FrameManifest;
use crate::tokenize::vocab::Vocabulary;
use anyhow::{bail, Result};
use candle_core::Device;
use std::collections::BTreeMap;
use std::path::Path;

/// The starting point of `--init-from`: a frame-model checkpoint folder
/// (its state and weights) or an exported model folder (its manifest's
/// vocabulary, and the weights read back from `global.onnx` and
/// `local.onnx`). An export's class heads (`cls.*`) are left out: they
/// were fitted in closed form on other inputs (`fit-heads`) and mean
/// nothing to the trainer's heads, which start fresh. Returns the
/// vocabulary, the tensors by name, the file they came from and the
/// lineage a child run records as its parent (see [`FrameState::parent`]).
pub fn init_source(
    from: &Path,
    dev: &Device,
) -> Result<(
    Vocabulary,
    BTreeMap<String, candle_core::Tensor>,
    String,
    serde_json::Value,
)> {
    use crate::lm::frame::FRAME_KIND;
    if from.join(crate::lm::manifest::MANIFEST_FILE).is_file() {
        let (file, name, m): (_, _, FrameManifest) = crate::lm::manifest::read_manifest(from)?;
        if m.kind != FRAME_KIND {
            bail!("{name}: field `kind`: {:?}, want {FRAME_KIND:?}", m.kind);
        }
        let dir = file.parent().unwrap_or(Path::new("."));
        let mut t = BTreeMap::new();
        for (onnx, sha) in [
            (&m.global_onnx, &m.global_sha256),
            (&m.local_onnx, &m.local_sha256),
        ] {
            let (path, _) = crate::lm::manifest::read_onnx_checked(&file, &name, onnx, sha)?;
            let got = super::frame_export::graph_weights(&path, dev)?;
            t.extend(got.into_iter().filter(|(k, _)| !k.starts_with("cls.")));
        }
        let tr = &m.training;
        let total = tr["total_train_seconds"]
            .as_f64()
            .or(tr["train_seconds"].as_f64())
            .unwrap_or(0.0);
        let lineage = serde_json::json!({
            "source": "exported model",
            "steps": tr["steps"],
            "train_seconds": total,
            "data": m.data,
            "parent": tr["parent"],
        });
        return Ok((m.vocabulary, t, dir.display().to_string(), lineage));
    }
    let (st, t, file): (FrameState, _, _) = super::load_parts(from, dev)?;
    let lineage = serde_json::json!({
        "source": "checkpoint",
        "steps": st.step,
        "train_seconds": st.train_seconds + lineage_seconds(st.parent.as_ref()),
        "data": st.data,
        "parent": st.parent,
    });
    Ok((st.vocabulary, t, file, lineage))
}

/// Training seconds of a lineage record (its parents included).
pub fn lineage_seconds(parent: Option<&serde_json::Value>) -> f64 {
    parent
        .and_then(|p| p["train_seconds"].as_f64())
        .unwrap_or(0.0)
}

/// Every licence in `data` and in the lineage's data, once each, sorted:
/// what a manifest must name for weights that started from a parent.
pub fn licences_with_parents(
    data: &crate::lm::manifest::DataInfo,
    parent: Option<&serde_json::Value>,
) -> Vec<String> {
    let mut all = data.licences.clone();
    let mut p = parent;
    while let Some(v) = p.filter(|v| !v.is_null()) {
        if let Some(ls) = v["data"]["licences"].as_array() {
            all.extend(ls.iter().filter_map(|l| l.as_str().map(String::from)));
        }
        p = v.get("parent");
    }
    all.sort();
    all.dedup();
    all
}

/// The trainer's network rebuilt from an exported frame model folder,
/// with class heads for `classes` (kind, values) in place of the export's
/// (those start fresh: the export's are fitted on other inputs). Every
/// other parameter must come from the graphs. Returns the manifest and
/// vocabulary beside it.
pub fn net_from_export(
    dir: &Path,
    classes: Vec<(String, Vec<String>)>,
    dev: &Device,
) -> Result<(FrameManifest, Vocabulary, FrameNet)> {
    let (_, _, m): (_, _, FrameManifest) = crate::lm::manifest::read_manifest(dir)?;
    let (vocab, tensors, file, _) = init_source(dir, dev)?;
    let net = FrameNet::new(
        crate::lm::frame::FrameConfig {
            classes,
            ..m.config.clone()
        },
        dev,
    )?;
    let fresh = net.params.load_matching(&tensors, &file)?;
    if let Some(n) = fresh.iter().find(|n| !n.starts_with("cls.")) {
        bail!("{}: the graphs lack the weight {n}", dir.display());
    }
    Ok((m, vocab, net))
}
