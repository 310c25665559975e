//! Readers and writers. Each parses bytes it is handed (no I/O below
//! [`read_path`] / [`write_path`]) and returns an error naming the file, the
//! field and the reason on bad input — never a panic, never an allocation
//! sized by an untrusted header.

pub mod aist;
pub mod amass;
pub mod bvh;
pub mod gltf;
pub mod json;
pub mod npy;
pub mod pickle;

use super::{Motion, MotionError};
use serde::Serialize;
use std::path::Path;

/// Largest file read (BVH text of 10 M frames would be far below this).
pub const MAX_FILE_BYTES: u64 = 2 << 30;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// The official AIST++ motion pickle.
    Aist,
    /// AMASS `.npz`.
    Amass,
    Bvh,
    /// choreo's JSON motion ([`json::MotionJson`]).
    Json,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::Aist => "aist",
            Format::Amass => "amass",
            Format::Bvh => "bvh",
            Format::Json => "json",
        }
    }

    /// By the name's extension only: a file's content is never guessed
    /// (a `.txt` that happens to start like a pickle is refused, not read
    /// as one).
    pub fn detect(path: &str, _bytes: &[u8]) -> Option<Format> {
        let lower = path.to_ascii_lowercase();
        if lower.ends_with(".pkl") || lower.ends_with(".pickle") {
            Some(Format::Aist)
        } else if lower.ends_with(".npz") {
            Some(Format::Amass)
        } else if lower.ends_with(".bvh") {
            Some(Format::Bvh)
        } else if lower.ends_with(".json") {
            Some(Format::Json)
        } else {
            None
        }
    }
}

#[derive(Clone, Debug, Default)]
pub struct ReadOptions {
    pub bvh: bvh::BvhReadOptions,
}

/// A motion as read, with what the format itself said about it.
pub struct Loaded {
    pub motion: Motion,
    pub format: Format,
    /// The channel layout, for a BVH input (so writing can keep it).
    pub bvh_layout: Option<bvh::BvhLayout>,
}

/// Parse a file's bytes; `file` names it in errors and gives the labels.
pub fn read_bytes(file: &str, bytes: &[u8], opts: &ReadOptions) -> Result<Loaded, MotionError> {
    let format = Format::detect(file, bytes).ok_or_else(|| MotionError::Unsupported {
        file: file.to_string(),
        reason:
            "the name's extension gives the format, and this one is not known (expected .pkl AIST++, .npz AMASS, .bvh or choreo .json)"
                .into(),
    })?;
    match format {
        Format::Aist => Ok(Loaded {
            motion: aist::read_aist_pickle(file, bytes)?,
            format,
            bvh_layout: None,
        }),
        Format::Amass => Ok(Loaded {
            motion: amass::read_amass_npz(file, bytes)?,
            format,
            bvh_layout: None,
        }),
        Format::Json => Ok(Loaded {
            motion: json::read_json(file, bytes)?,
            format,
            bvh_layout: None,
        }),
        Format::Bvh => {
            let text = std::str::from_utf8(bytes).map_err(|e| {
                MotionError::invalid(file, "text", format!("not UTF-8/ASCII text ({e})"))
            })?;
            let b = bvh::read_bvh(file, text, &opts.bvh)?;
            Ok(Loaded {
                motion: b.motion,
                format,
                bvh_layout: Some(b.layout),
            })
        }
    }
}

pub fn read_path(path: &Path, opts: &ReadOptions) -> Result<Loaded, MotionError> {
    let file = path.display().to_string();
    let io = |source| MotionError::Io {
        file: file.clone(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(io)?;
    if meta.len() > MAX_FILE_BYTES {
        return Err(MotionError::invalid(
            &file,
            "size",
            format!(
                "{} bytes is over the {MAX_FILE_BYTES}-byte limit",
                meta.len()
            ),
        ));
    }
    let bytes = std::fs::read(path).map_err(io)?;
    read_bytes(&file, &bytes, opts)
}

/// Write by the extension of `path`: `.bvh`, `.npz` or `.json`. The file appears
/// whole or not at all (written beside, then renamed).
pub fn write_path(
    m: &Motion,
    path: &Path,
    bvh_opts: &bvh::BvhWriteOptions<'_>,
) -> Result<(), MotionError> {
    let file = path.display().to_string();
    let lower = file.to_ascii_lowercase();
    let bytes = if lower.ends_with(".bvh") {
        bvh::write_bvh(m, bvh_opts)?.into_bytes()
    } else if lower.ends_with(".npz") {
        amass::write_amass_npz(m)?
    } else if lower.ends_with(".json") {
        m.validate()?;
        json::write_json(m)
    } else if lower.ends_with(".glb") {
        gltf::write_glb(m)?
    } else {
        return Err(MotionError::Unsupported {
            file,
            reason: "output format must be .bvh, .npz, .json or .glb".into(),
        });
    };
    let tmp = path.with_extension("partial");
    let io = |source| MotionError::Io {
        file: file.clone(),
        source,
    };
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}
