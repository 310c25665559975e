//! Helpers shared by the model tests: a small vocabulary, a small frame
//! model configuration, and its export to a temporary folder.

use choreo::lm::frame::FrameConfig;
use choreo::lm::manifest::DataInfo;
use choreo::tokenize::vocab::Vocabulary;
use choreo::train::frame::FrameNet;
use choreo::train::frame_export;
use std::collections::{BTreeMap, BTreeSet};

/// A vocabulary whose only label kind is `style` (happy, sad).
pub fn style_vocab() -> Vocabulary {
    let mut labels: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    labels.insert(
        "style".into(),
        ["happy", "sad"].iter().map(|s| s.to_string()).collect(),
    );
    Vocabulary::new(labels)
}

/// A frame model small enough to train and export in a test, conditioned
/// on `style` at every frame, with a `style` class head.
pub fn small_frame_config(v: &Vocabulary, max_frames: usize) -> FrameConfig {
    FrameConfig {
        bins: v.bins,
        slots: v.frame_len() - 1,
        radius: 12,
        d_emb: 8,
        d_global: 32,
        global_layers: 2,
        global_heads: 4,
        d_local: 32,
        local_layers: 1,
        local_heads: 4,
        max_frames,
        vocab_size: v.size(),
        cond_kinds: vec!["style".into()],
        classes: vec![("style".into(), vec!["happy".into(), "sad".into()])],
        ln_eps: 1e-5,
        cond_every: true,
    }
}

/// Exports a frame model (both graphs and the manifest) to a fresh
/// temporary folder.
pub fn export_frame(net: &FrameNet, v: &Vocabulary) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    frame_export::export(
        net,
        v,
        DataInfo::default(),
        BTreeMap::new(),
        serde_json::json!({}),
        dir.path(),
    )
    .unwrap();
    dir
}
