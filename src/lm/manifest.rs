//! The manifest written beside an exported ONNX file: what the graph is,
//! which vocabulary and tokenizer settings it was trained with, where its
//! data came from, and what it measured. The server refuses an ONNX file
//! whose hash does not match its manifest.

use super::{LmError, ModelConfig};
use crate::tokenize::vocab::Vocabulary;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub const MANIFEST_FORMAT: u32 = 1;
pub const MANIFEST_FILE: &str = "manifest.json";

/// Where the training data came from.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DataInfo {
    /// The corpora's folders, relative to the data root.
    pub corpora: Vec<String>,
    pub files: usize,
    pub train_sequences: usize,
    pub val_sequences: usize,
    pub train_tokens: usize,
    /// SHA-256 over the sorted (path, size) list of the files read.
    pub sha256: String,
    pub licences: Vec<String>,
    /// Corpora whose training takes sharing every label but the take were
    /// played one after another (`choreo-train --chain-takes`); absent =
    /// none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub chained_takes: Vec<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: u32,
    /// `motion-lm` (the language model) or `inbetweener`.
    pub kind: String,
    pub config: ModelConfig,
    pub vocabulary: Vocabulary,
    /// The ONNX file, relative to the manifest.
    pub onnx: String,
    pub onnx_sha256: String,
    pub data: DataInfo,
    /// Graph input and output names, in order.
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    /// Held-out figures (validation loss, bits/frame, accuracies …).
    pub metrics: BTreeMap<String, f64>,
    /// How it was trained (regime, steps, learning rate, parent checkpoint …).
    pub training: serde_json::Value,
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Reads `dir/manifest.json` (or the file itself when `path` is one):
/// the file, its display name and the parsed manifest.
pub fn read_manifest<T: serde::de::DeserializeOwned>(
    path: &Path,
) -> Result<(PathBuf, String, T), LmError> {
    let file = if path.is_dir() {
        path.join(MANIFEST_FILE)
    } else {
        path.to_path_buf()
    };
    let name = file.display().to_string();
    let text = std::fs::read_to_string(&file).map_err(|e| LmError::Io {
        file: name.clone(),
        reason: e.to_string(),
    })?;
    let m =
        serde_json::from_str(&text).map_err(|e| LmError::invalid(&name, "json", e.to_string()))?;
    Ok((file, name, m))
}

/// The ONNX file a manifest names (relative to it), checked against the
/// manifest's SHA-256.
pub fn read_onnx_checked(
    manifest_file: &Path,
    name: &str,
    onnx: &str,
    sha256: &str,
) -> Result<(PathBuf, Vec<u8>), LmError> {
    let onnx_path = manifest_file.parent().unwrap_or(Path::new(".")).join(onnx);
    let bytes = std::fs::read(&onnx_path).map_err(|e| LmError::Io {
        file: onnx_path.display().to_string(),
        reason: e.to_string(),
    })?;
    let got = sha256_hex(&bytes);
    if got != sha256 {
        return Err(LmError::invalid(
            name,
            "onnx_sha256",
            format!(
                "{sha256} does not match {} (sha256 {got}): the manifest belongs to another export",
                onnx_path.display()
            ),
        ));
    }
    Ok((onnx_path, bytes))
}

impl Manifest {
    /// Reads `dir/manifest.json` (or the file itself when `path` is one) and
    /// checks it against its ONNX file. Returns the manifest and the ONNX
    /// bytes.
    pub fn load(path: &Path) -> Result<(Manifest, PathBuf, Vec<u8>), LmError> {
        let (file, name, m): (PathBuf, String, Manifest) = read_manifest(path)?;
        if m.format != MANIFEST_FORMAT {
            return Err(LmError::invalid(
                &name,
                "format",
                format!("{} (this build reads format {MANIFEST_FORMAT})", m.format),
            ));
        }
        m.config.validate(&name)?;
        m.vocabulary
            .validate()
            .map_err(|e| LmError::invalid(&name, "vocabulary", e.to_string()))?;
        if m.vocabulary.size() != m.config.vocab_size {
            return Err(LmError::invalid(
                &name,
                "config.vocab_size",
                format!(
                    "{} but the vocabulary has {} tokens",
                    m.config.vocab_size,
                    m.vocabulary.size()
                ),
            ));
        }
        let (onnx_path, bytes) = read_onnx_checked(&file, &name, &m.onnx, &m.onnx_sha256)?;
        Ok((m, onnx_path, bytes))
    }

    pub fn save(&self, dir: &Path) -> Result<(), LmError> {
        let p = dir.join(MANIFEST_FILE);
        let text = serde_json::to_string_pretty(self).expect("manifest serialises");
        std::fs::write(&p, text + "\n").map_err(|e| LmError::Io {
            file: p.display().to_string(),
            reason: e.to_string(),
        })
    }
}
