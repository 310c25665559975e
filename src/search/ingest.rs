//! Ingest: walk paths, read every supported motion file, cut windows, embed
//! them, and store each file in its own transaction (a crash loses at most
//! the file in progress). Files already stored (same content hash) are
//! skipped; a bad file is reported, never fatal. The PCA basis is refitted on
//! all stored windows afterwards.

use crate::features::pca::PcaAccumulator;
use crate::features::{
    channels72, window, window_starts, Embedding, Extractor, Pca, StftParams, WINDOW,
};
use crate::lm::embed::LmEmbedder;
use crate::motion::io::{read_bytes, ReadOptions};
use crate::motion::{Labels, Motion, MotionError};
use crate::store::{Inserted, MotionRow, NewMotion, NewWindow, Store, StoreError, VideoLink};
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

#[derive(Clone, Debug)]
pub struct IngestOptions {
    /// Window hop in frames at 60 fps (SPEC default 32).
    pub hop: usize,
    pub stft: StftParams,
    pub read: ReadOptions,
    /// Labels added to every motion of this ingest (e.g. `dancer=anna`,
    /// `rehearsal=2026-11-20`); they override labels parsed from names.
    pub extra_labels: Labels,
    /// Keep the file's bytes in the store (`motion_files`), so the motion
    /// can be read back without the file (always on for API uploads).
    pub keep_files: bool,
    /// The footage the file was estimated from, and the video time of its
    /// first row (a WHAM-style file's first `frame_ids` is added to it).
    pub video: Option<VideoLink>,
    /// The collection the motions go into (it must exist).
    pub collection: String,
}

impl Default for IngestOptions {
    fn default() -> Self {
        IngestOptions {
            hop: 32,
            stft: StftParams::default(),
            read: ReadOptions::default(),
            extra_labels: Labels::new(),
            keep_files: false,
            video: None,
            collection: DEFAULT_COLLECTION.into(),
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct FileError {
    pub file: String,
    pub reason: String,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct IngestReport {
    pub files: usize,
    pub motions: usize,
    pub windows: usize,
    pub skipped: usize,
    pub errors: Vec<FileError>,
}

pub const MOTION_EXTENSIONS: [&str; 4] = ["pkl", "pickle", "npz", "bvh"];

/// Every motion file under the given files/folders, sorted, deduplicated.
pub fn collect_files(paths: &[PathBuf]) -> Vec<PathBuf> {
    collect_files_with(paths, &ReadOptions::default())
}

/// [`collect_files`] for a read with these options: with a keypoint layout,
/// folders give their `.npy` and `.json` files too.
pub fn collect_files_with(paths: &[PathBuf], read: &ReadOptions) -> Vec<PathBuf> {
    let mut exts = MOTION_EXTENSIONS.to_vec();
    if read.keypoints.is_some() {
        exts.extend(["npy", "json"]);
    }
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            out.extend(crate::data::files_with_ext(p, &exts));
        } else {
            out.push(p.clone());
        }
    }
    out.sort();
    out.dedup();
    out
}

/// The collection motions go into unless a request names another.
pub const DEFAULT_COLLECTION: &str = "default";

/// What makes a stored file unique: its content hash within its
/// collection. In `default` it is the plain SHA-256 (as before
/// collections); elsewhere the collection's name is hashed in, so the same
/// file may be stored in two collections, and an ingest never tells a
/// caller that a file exists in a collection it cannot see.
pub fn identity_hash(collection: &str, bytes: &[u8]) -> String {
    if collection == DEFAULT_COLLECTION {
        return content_hash(bytes);
    }
    let mut h = Sha256::new();
    h.update(b"choreo collection\0");
    h.update(collection.as_bytes());
    h.update(b"\0");
    h.update(bytes);
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

pub fn content_hash(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// Parse, cut and embed one file (blocking, CPU-heavy).
pub fn prepare(
    file: &str,
    bytes: Vec<u8>,
    hash: String,
    opts: &IngestOptions,
) -> Result<NewMotion, MotionError> {
    prepare_with(file, bytes, hash, opts, None, None)
}

/// [`prepare`], with PCA embeddings too when a basis is given (the live
/// server projects new windows on the basis it is serving), and `lm`
/// embeddings when the server's frame model embeds them.
pub fn prepare_with(
    file: &str,
    bytes: Vec<u8>,
    hash: String,
    opts: &IngestOptions,
    pca: Option<&Pca>,
    lm: Option<&LmEmbedder>,
) -> Result<NewMotion, MotionError> {
    let loaded = read_bytes(file, &bytes, &opts.read)?;
    let m = &loaded.motion;
    let ch = channels72(m)?;
    let ex = Extractor::new(opts.stft)?;
    let windows = window_starts(ch.len(), opts.hop)
        .into_iter()
        .map(|s| {
            let w = window(&ch, s);
            let lm = lm
                .map(|emb| emb.window(&w))
                .transpose()
                .map_err(|e| MotionError::invalid(file, "lm", e.to_string()))?;
            Ok(NewWindow {
                start_frame: s,
                frames: WINDOW,
                embeddings: [
                    (Embedding::Stft, ex.stft(&w)),
                    (Embedding::Dct, ex.dct(&w)),
                    (Embedding::Pose, ex.pose(&w)),
                ]
                .into_iter()
                .chain(pca.map(|p| (Embedding::Pca, p.project_window(&w))))
                .chain(lm.map(|v| (Embedding::Lm, v)))
                .collect(),
            })
        })
        .collect::<Result<Vec<_>, MotionError>>()?;
    Ok(NewMotion {
        source_path: file.to_string(),
        content_hash: hash,
        format: loaded.format.name().to_string(),
        fps: m.fps,
        frames: m.frames(),
        joints: m.joints(),
        skeleton: m.skeleton.kind.clone(),
        duration_s: m.duration_s(),
        labels: {
            let mut l = m.labels.clone();
            l.extend(opts.extra_labels.clone());
            l
        },
        channels: ch,
        windows,
        file: opts.keep_files.then(|| {
            let base = Path::new(file)
                .file_name()
                .map_or_else(|| file.to_string(), |n| n.to_string_lossy().into_owned());
            (base, bytes)
        }),
        read_options: opts.read.clone(),
        collection: opts.collection.clone(),
        video: opts.video.clone().map(|v| VideoLink {
            video_offset_s: v.video_offset_s
                + loaded
                    .footage
                    .as_ref()
                    .map_or(0.0, |f| f.first_frame as f64 / m.fps),
            ..v
        }),
    })
}

/// Ingest files and folders. `progress(done, total, file)` is called after
/// each file.
pub async fn ingest(
    store: &Store,
    paths: &[PathBuf],
    opts: &IngestOptions,
    progress: &(dyn Fn(usize, usize, &str) + Sync),
) -> Result<IngestReport, StoreError> {
    let files = collect_files_with(paths, &opts.read);
    let mut report = IngestReport {
        files: files.len(),
        ..Default::default()
    };
    for (i, path) in files.iter().enumerate() {
        let name = path.display().to_string();
        match ingest_one(store, path, opts).await? {
            Outcome::Stored(w) => {
                report.motions += 1;
                report.windows += w;
            }
            Outcome::Skipped => report.skipped += 1,
            Outcome::Failed(reason) => report.errors.push(FileError {
                file: name.clone(),
                reason,
            }),
        }
        progress(i + 1, files.len(), &name);
    }
    refresh_pca(store).await?;
    backfill_pose(store).await?;
    Ok(report)
}

enum Outcome {
    Stored(usize),
    Skipped,
    Failed(String),
}

async fn ingest_one(
    store: &Store,
    path: &Path,
    opts: &IngestOptions,
) -> Result<Outcome, StoreError> {
    let name = path.display().to_string();
    let bytes = match std::fs::metadata(path) {
        Ok(md) if md.len() > crate::motion::io::MAX_FILE_BYTES => {
            return Ok(Outcome::Failed(format!(
                "{name}: {} bytes is over the size limit",
                md.len()
            )))
        }
        Ok(_) => match std::fs::read(path) {
            Ok(b) => b,
            Err(e) => return Ok(Outcome::Failed(format!("{name}: {e}"))),
        },
        Err(e) => return Ok(Outcome::Failed(format!("{name}: {e}"))),
    };
    Ok(match ingest_bytes(store, &name, bytes, opts).await? {
        Ok(Stored::New { windows, .. }) => Outcome::Stored(windows),
        Ok(Stored::Existing { .. }) => Outcome::Skipped,
        Err(e) => Outcome::Failed(e.to_string()),
    })
}

/// What [`ingest_bytes`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum Stored {
    /// Stored as a new motion with this many windows.
    New { motion_id: i64, windows: usize },
    /// The same bytes were already stored (content hash): nothing written.
    Existing { motion_id: i64 },
}

/// Store one file's bytes (`name` gives the format and the labels): one
/// transaction, idempotent by content hash. Does not refit the PCA basis
/// ([`refresh_pca`]). The outer error is the store's; the inner one says
/// why the file itself was refused.
pub async fn ingest_bytes(
    store: &Store,
    name: &str,
    bytes: Vec<u8>,
    opts: &IngestOptions,
) -> Result<Result<Stored, MotionError>, StoreError> {
    let hash = identity_hash(&opts.collection, &bytes);
    if let Some(id) = store.motion_by_hash(&hash).await? {
        return Ok(Ok(Stored::Existing { motion_id: id }));
    }
    let opts2 = opts.clone();
    let name2 = name.to_string();
    let prepared = tokio::task::spawn_blocking(move || prepare(&name2, bytes, hash, &opts2))
        .await
        .map_err(|e| MotionError::invalid(name, "ingest", format!("worker failed: {e}")));
    match prepared {
        Ok(Ok(m)) => {
            let windows = m.windows.len();
            Ok(Ok(match store.insert_motion(&m).await? {
                Inserted::New { id, .. } => Stored::New {
                    motion_id: id,
                    windows,
                },
                // Another replica stored it since the lookup.
                Inserted::Existing(id) => Stored::Existing { motion_id: id },
            }))
        }
        Ok(Err(e)) | Err(e) => Ok(Err(e)),
    }
}

/// A stored motion's row and source bytes (with the name that gives their
/// format): the bytes the store kept, else its source path, which must
/// still hold the same content.
pub async fn load_source(
    store: &Store,
    id: i64,
) -> Result<Option<(MotionRow, String, Vec<u8>)>, LoadError> {
    let Some(row) = store.motion(id).await? else {
        return Ok(None);
    };
    if let Some((name, bytes)) = store.motion_file(id).await? {
        return Ok(Some((row, name, bytes)));
    }
    let path = row.source_path.clone();
    let bytes = tokio::task::spawn_blocking(move || std::fs::read(&path))
        .await
        .map_err(|e| LoadError::Gone(format!("{}: {e}", row.source_path)))?
        .map_err(|e| {
            LoadError::Gone(format!(
                "motion {id}: the store keeps no copy and {} cannot be read ({e})",
                row.source_path
            ))
        })?;
    if identity_hash(&row.collection, &bytes) != row.content_hash {
        return Err(LoadError::Gone(format!(
            "motion {id}: the store keeps no copy and {} has changed since it was ingested",
            row.source_path
        )));
    }
    let name = row.source_path.clone();
    Ok(Some((row, name, bytes)))
}

/// A stored motion, read back whole ([`load_source`], parsed), with the
/// stored labels.
pub async fn load_motion(store: &Store, id: i64) -> Result<Option<(MotionRow, Motion)>, LoadError> {
    let Some((row, name, bytes)) = load_source(store, id).await? else {
        return Ok(None);
    };
    let mut m = parse_source(id, name, bytes, row.read_options.clone()).await?;
    m.labels = row.labels.clone();
    Ok(Some((row, m)))
}

/// Parse source bytes on the blocking pool, the way they were read at ingest.
pub async fn parse_source(
    id: i64,
    name: String,
    bytes: Vec<u8>,
    read: ReadOptions,
) -> Result<Motion, LoadError> {
    Ok(
        tokio::task::spawn_blocking(move || read_bytes(&name, &bytes, &read).map(|l| l.motion))
            .await
            .map_err(|e| LoadError::Gone(format!("motion {id}: worker failed: {e}")))??,
    )
}

#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Motion(#[from] MotionError),
    /// The motion's source is no longer readable.
    #[error("{0}")]
    Gone(String),
}

/// Refit the PCA basis on every stored window when the windows changed since
/// the last fit, and re-embed all windows with it (one transaction).
pub async fn refresh_pca(store: &Store) -> Result<Option<Pca>, StoreError> {
    let fp = store.windows_fingerprint().await?;
    if let Some((g, body)) = store.model("pca").await? {
        if g == fp {
            return Ok(serde_json::from_str(&body).ok());
        }
    }
    Ok(refit_pca(store).await?.map(|(p, _)| p))
}

/// Give every stored window its pose embedding when some lack it (a store
/// written before the pose embedding existed): all are computed again from
/// the stored channels, in one transaction. Returns how many were written.
pub async fn backfill_pose(store: &Store) -> Result<usize, StoreError> {
    let (_, nwin) = store.counts().await?;
    if store.count_embeddings(Embedding::Pose).await? == nwin {
        return Ok(0);
    }
    let fp = store.windows_fingerprint().await?;
    let channels = store.all_channels().await?;
    let windows = store.windows().await?;
    let rows = tokio::task::spawn_blocking(move || {
        let ex = Extractor::new(StftParams::default()).expect("default STFT");
        let by_motion: std::collections::HashMap<i64, &Vec<[f32; 72]>> =
            channels.iter().map(|(id, c)| (*id, c)).collect();
        windows
            .iter()
            .filter_map(|(id, w)| {
                by_motion
                    .get(&w.motion_id)
                    .map(|ch| (*id, ex.pose(&window(ch, w.start_frame as usize))))
            })
            .collect::<Vec<_>>()
    })
    .await
    .map_err(|e| StoreError::Corrupt {
        path: store.path().display().to_string(),
        field: "pose".into(),
        reason: format!("worker failed: {e}"),
    })?;
    let n = rows.len();
    tracing::info!("pose embeddings computed for {n} stored windows");
    store
        .replace_embeddings(Embedding::Pose, &rows, "pose", "{\"version\":1}", fp)
        .await?;
    Ok(n)
}

/// The stored PCA basis, if any.
pub async fn stored_pca(store: &Store) -> Result<Option<Pca>, StoreError> {
    Ok(store
        .model("pca")
        .await?
        .and_then(|(_, body)| serde_json::from_str(&body).ok()))
}

/// Share of windows added or removed since the PCA fit past which a live
/// server refits it (between refits, new windows are projected on the
/// basis in service: a fixed linear map, so answers stay consistent).
pub const PCA_DRIFT: f64 = 0.10;

/// Whether the PCA basis must be refitted: there is none while windows
/// exist, some window has no PCA embedding, or the window count drifted
/// past [`PCA_DRIFT`] since the fit.
pub async fn pca_due(store: &Store) -> Result<bool, StoreError> {
    let (_, nwin) = store.counts().await?;
    if nwin == 0 {
        return Ok(false);
    }
    let Some((fp, _)) = store.model("pca").await? else {
        return Ok(true);
    };
    if store.count_embeddings(Embedding::Pca).await? != nwin {
        return Ok(true);
    }
    // The fingerprint is `count · 1_000_000_007 + max id`.
    let fitted = (fp / 1_000_000_007) as f64;
    Ok((nwin as f64 - fitted).abs() > PCA_DRIFT * fitted.max(1.0))
}

/// Fit the PCA basis on every stored window, re-embed all windows with it
/// and store both (one transaction). Returns the basis and the rows.
pub async fn refit_pca(store: &Store) -> Result<Option<(Pca, Vec<(i64, Vec<f32>)>)>, StoreError> {
    let fp = store.windows_fingerprint().await?;
    let (_, nwin) = store.counts().await?;
    if nwin == 0 {
        return Ok(None);
    }
    let channels = store.all_channels().await?;
    let windows = store.windows().await?;
    let corrupt = |reason: String| StoreError::Corrupt {
        path: store.path().display().to_string(),
        field: "pca".into(),
        reason,
    };
    let (pca, rows) = tokio::task::spawn_blocking(move || {
        let by_motion: std::collections::HashMap<i64, &Vec<[f32; 72]>> =
            channels.iter().map(|(id, c)| (*id, c)).collect();
        let mut acc = PcaAccumulator::default();
        for (_, w) in &windows {
            if let Some(ch) = by_motion.get(&w.motion_id) {
                acc.add_window(&window(ch, w.start_frame as usize));
            }
        }
        let pca = acc.finish()?;
        let rows: Vec<(i64, Vec<f32>)> = windows
            .iter()
            .filter_map(|(id, w)| {
                by_motion
                    .get(&w.motion_id)
                    .map(|ch| (*id, pca.project_window(&window(ch, w.start_frame as usize))))
            })
            .collect();
        Ok::<_, MotionError>((pca, rows))
    })
    .await
    .map_err(|e| corrupt(format!("worker failed: {e}")))?
    .map_err(|e| corrupt(e.to_string()))?;
    let body = serde_json::to_string(&pca).expect("PCA serialises");
    store
        .replace_embeddings(Embedding::Pca, &rows, "pca", &body, fp)
        .await?;
    Ok(Some((pca, rows)))
}
