//! Readers and writers. Each parses bytes it is handed (no I/O below
//! [`read_path`] / [`write_path`]) and returns an error naming the file, the
//! field and the reason on bad input — never a panic, never an allocation
//! sized by an untrusted header.

pub mod aist;
pub mod amass;
pub mod bvh;
pub mod gltf;
pub mod json;
pub mod keypoints;
pub mod npy;
pub mod pickle;
pub mod smpl_params;

use super::keypoints::{FootageReport, Layout, SolveOptions, Up};
use super::{Motion, MotionError};
use serde::{Deserialize, Serialize};
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
    /// choreo's JSON motion ([`json::MotionFile`]).
    Json,
    /// Keypoints from a video pose estimator (`.npy`, or keypoint `.json`
    /// when a layout is given), solved onto SMPL by inverse kinematics.
    Keypoints,
    /// SMPL parameters from a video estimator (WHAM-style `.npz` / `.pkl`).
    Smpl,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::Aist => "aist",
            Format::Amass => "amass",
            Format::Bvh => "bvh",
            Format::Json => "json",
            Format::Keypoints => "keypoints",
            Format::Smpl => "smpl",
        }
    }

    /// By the name's extension only: a file's content is never guessed
    /// (a `.txt` that happens to start like a pickle is refused, not read
    /// as one).
    pub fn detect(path: &str, _bytes: &[u8]) -> Option<Format> {
        let lower = path.to_ascii_lowercase();
        if lower.ends_with(".npy") {
            Some(Format::Keypoints)
        } else if lower.ends_with(".pkl") || lower.ends_with(".pickle") {
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

/// How to read a file beyond what its name says. Stored with every motion
/// (as JSON) so that the store reads it back the same way.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReadOptions {
    #[serde(default, skip_serializing_if = "bvh::BvhReadOptions::is_default")]
    pub bvh: bvh::BvhReadOptions,
    /// The keypoint layout of a `.npy` or keypoint `.json`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keypoints: Option<Layout>,
    /// Frame rate of a file that carries none (keypoints, SMPL from video);
    /// overrides a keypoint JSON's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    /// The file's up axis, where it is not the format's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<Up>,
    /// Keypoint confidence below which a frame is flagged and bridged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_confidence: Option<f64>,
    /// Keypoint smoothing before the solve (Gaussian σ, seconds; 0 = off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smooth_s: Option<f64>,
}

impl ReadOptions {
    pub fn is_default(&self) -> bool {
        *self == ReadOptions::default()
    }
}

/// A motion as read, with what the format itself said about it.
pub struct Loaded {
    pub motion: Motion,
    pub format: Format,
    /// The channel layout, for a BVH input (so writing can keep it).
    pub bvh_layout: Option<bvh::BvhLayout>,
    /// For motions from video (keypoints, SMPL parameters): what the solver
    /// found (flagged frames, scale, confidence).
    pub footage: Option<FootageReport>,
}

impl Loaded {
    fn plain(motion: Motion, format: Format) -> Self {
        Loaded {
            motion,
            format,
            bvh_layout: None,
            footage: None,
        }
    }
    fn footage(format: Format, (motion, report): (Motion, FootageReport)) -> Self {
        Loaded {
            motion,
            format,
            bvh_layout: None,
            footage: Some(report),
        }
    }
}

fn keypoint_motion(
    file: &str,
    kp: super::keypoints::Keypoints,
    opts: &ReadOptions,
) -> Result<Loaded, MotionError> {
    let defaults = SolveOptions::new(kp.layout);
    let so = SolveOptions {
        up: opts.up.unwrap_or(defaults.up),
        min_confidence: opts.min_confidence.unwrap_or(defaults.min_confidence),
        smooth_s: opts.smooth_s.unwrap_or(defaults.smooth_s),
        ..defaults
    };
    let (mut m, report) = super::keypoints::solve(file, &kp, &so)?;
    m.labels = super::labels::from_name(file);
    m.labels
        .entry("corpus".into())
        .or_insert_with(|| "video".into());
    Ok(Loaded::footage(Format::Keypoints, (m, report)))
}

/// Parse a file's bytes; `file` names it in errors and gives the labels.
pub fn read_bytes(file: &str, bytes: &[u8], opts: &ReadOptions) -> Result<Loaded, MotionError> {
    let mut format = Format::detect(file, bytes).ok_or_else(|| MotionError::Unsupported {
        file: file.to_string(),
        reason:
            "the name's extension gives the format, and this one is not known (expected .pkl AIST++ or SMPL parameters, .npz AMASS or SMPL parameters, .bvh, choreo .json, or keypoints .npy/.json)"
                .into(),
    })?;
    if format == Format::Json && opts.keypoints.is_some() {
        format = Format::Keypoints;
    }
    if format != Format::Keypoints && opts.keypoints.is_some() {
        return Err(MotionError::invalid(
            file,
            "keypoints",
            "a keypoint layout applies to .npy and keypoint .json files only",
        ));
    }
    match format {
        Format::Keypoints => {
            let layout = opts.keypoints.ok_or_else(|| {
                MotionError::invalid(
                    file,
                    "keypoints",
                    "missing: a .npy holds keypoints; name the layout (--keypoints h36m17|mediapipe33, API `keypoints`)",
                )
            })?;
            let lower = file.to_ascii_lowercase();
            let kp = if lower.ends_with(".npy") {
                keypoints::read_npy(file, bytes, layout, opts.fps)?
            } else {
                keypoints::read_json(file, bytes, layout, opts.fps)?
            };
            keypoint_motion(file, kp, opts)
        }
        Format::Aist => {
            let root = smpl_params::load_pickle(file, bytes)?;
            if smpl_params::is_smpl_params(&root) {
                smpl_params::read_pickle_value(file, &root, opts.fps, opts.up)
                    .map(|r| Loaded::footage(Format::Smpl, r))
            } else {
                Ok(Loaded::plain(aist::read_aist_value(file, &root)?, format))
            }
        }
        Format::Amass | Format::Smpl => {
            if npz_has_any(bytes, &smpl_params::POSE_KEYS) && !npz_has_any(bytes, &["poses"]) {
                smpl_params::read_npz(file, bytes, opts.fps, opts.up)
                    .map(|r| Loaded::footage(Format::Smpl, r))
            } else {
                Ok(Loaded::plain(
                    amass::read_amass_npz(file, bytes)?,
                    Format::Amass,
                ))
            }
        }
        Format::Json => Ok(Loaded::plain(json::read_json(file, bytes)?, format)),
        Format::Bvh => {
            let text = std::str::from_utf8(bytes).map_err(|e| {
                MotionError::invalid(file, "text", format!("not UTF-8/ASCII text ({e})"))
            })?;
            let b = bvh::read_bvh(file, text, &opts.bvh)?;
            Ok(Loaded {
                motion: b.motion,
                format,
                bvh_layout: Some(b.layout),
                footage: None,
            })
        }
    }
}

/// Whether an `.npz` archive holds an array under any of `keys`.
fn npz_has_any(bytes: &[u8], keys: &[&str]) -> bool {
    zip::ZipArchive::new(std::io::Cursor::new(bytes)).is_ok_and(|z| {
        z.file_names()
            .any(|n| keys.iter().any(|k| n.strip_suffix(".npy") == Some(*k)))
    })
}

pub fn read_path(path: &Path, opts: &ReadOptions) -> Result<Loaded, MotionError> {
    let file = path.display().to_string();
    let io = |error| MotionError::Io {
        file: file.clone(),
        error,
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
    let io = |error| MotionError::Io {
        file: file.clone(),
        error,
    };
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}
