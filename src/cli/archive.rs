//! The store on the command line: ingest and query.

use super::args::*;
use super::{parse_pairs, runtime};
use anyhow::{bail, Context, Result};
use choreo::features::Embedding;
use choreo::index::hnsw::HnswParams;
use choreo::motion::io::{self};
use choreo::search::ingest::IngestOptions;
use choreo::search::{QueryRequest, Searcher};
use choreo::service::query;
use choreo::store::Store;
use serde_json::json;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct IngestArgs {
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    #[arg(long, env = "CHOREO_DB", default_value = "choreo.db")]
    pub db: PathBuf,
    /// Window hop in frames at 60 fps.
    #[arg(long, default_value_t = 32)]
    pub hop: usize,
    /// KIND=VALUE added to every motion ingested now (repeatable).
    #[arg(long)]
    pub label: Vec<String>,
    /// Keep each file's bytes in the database, so `get` / `export`
    /// work after the files move (the store grows by their size).
    #[arg(long)]
    pub keep_files: bool,
    /// The footage the (single) file was estimated from, a path or URL:
    /// query hits then give the video time of each match.
    #[arg(long)]
    pub video: Option<String>,
    /// Video time of the file's first frame, seconds.
    #[arg(long, requires = "video", allow_hyphen_values = true)]
    pub video_offset: Option<f64>,
    /// The collection the motions go into (created if missing; the
    /// command line has the whole store).
    #[arg(long, default_value = "default")]
    pub collection: String,
    /// A frame model folder: every stored window also gets its `lm`
    /// vector from it (its class heads' reading), so `query --embedding
    /// lm` and a server with the same model find them ready.
    #[arg(long)]
    pub model: Option<PathBuf>,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: ReadArgs,
    #[command(flatten)]
    pub fps: SourceFps,
}

#[derive(clap::Args)]
pub struct QueryArgs {
    #[arg(long, env = "CHOREO_DB", default_value = "choreo.db")]
    pub db: PathBuf,
    #[arg(long)]
    pub motion: PathBuf,
    /// Segment start, seconds.
    #[arg(long, default_value_t = 0.0)]
    pub start: f64,
    /// Segment length in frames at 60 fps (at least 128).
    #[arg(long, default_value_t = query::DEFAULT_FRAMES)]
    pub frames: usize,
    #[arg(long, default_value_t = query::DEFAULT_K)]
    pub k: usize,
    /// stft, dct, pca, pose or lm (default: pose for keypoint /
    /// SMPL-from-video files, i.e. with --keypoints or --source-fps; stft
    /// otherwise, as over the API). lm needs --model.
    #[arg(long)]
    pub embedding: Option<String>,
    /// A frame model folder, for the lm embedding.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// cosine (the default) or euclidean.
    #[arg(long)]
    pub metric: Option<String>,
    /// KIND=VALUE, repeatable: hits must carry every label.
    #[arg(long)]
    pub filter: Vec<String>,
    /// Exact search instead of HNSW.
    #[arg(long)]
    pub exact: bool,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: ReadArgs,
    #[command(flatten)]
    pub fps: SourceFps,
}

pub fn ingest_cmd(a: IngestArgs) -> Result<()> {
    let IngestArgs {
        paths,
        db,
        hop,
        label,
        keep_files,
        video,
        video_offset,
        collection,
        model,
        json,
        read,
        fps,
    } = a;
    let lm = model.as_deref().map(load_lm).transpose()?;
    let read = read.with_fps(&fps)?;
    let labels = parse_pairs("--label", &label)?.into_iter().collect();
    if video.is_some() && (paths.len() != 1 || paths[0].is_dir()) {
        bail!("--video links one file: give exactly one file to ingest with it");
    }
    if let Some(o) = video_offset {
        if !o.is_finite() {
            bail!("--video-offset: {o} is not a number of seconds");
        }
    }
    let opts = IngestOptions {
        hop,
        extra_labels: labels,
        keep_files,
        read: read.options(),
        video: video.map(|video| choreo::store::VideoLink {
            video,
            video_offset_s: video_offset.unwrap_or(0.0),
        }),
        collection,
        ..Default::default()
    };
    runtime()?.block_on(ingest(paths, db, opts, lm, json))
}

/// The `lm` embedder of a frame model folder.
fn load_lm(dir: &std::path::Path) -> Result<choreo::lm::embed::LmEmbedder> {
    let m = choreo::lm::model::MotionModel::load(dir)
        .with_context(|| format!("--model {}", dir.display()))?;
    Ok(choreo::lm::embed::LmEmbedder::new(&m).context("--model")?)
}

pub fn query_cmd(a: QueryArgs) -> Result<()> {
    let QueryArgs {
        db,
        motion,
        start,
        frames,
        k,
        embedding,
        model,
        metric,
        filter,
        exact,
        json,
        read,
        fps,
    } = a;
    let read = read.with_fps(&fps)?;
    let footage = read.keypoints.is_some() || read.source_fps.is_some();
    let embedding = query::embedding_or_default(embedding.as_deref().unwrap_or(""), footage)
        .map_err(|e| anyhow::anyhow!("--{e}"))?;
    let lm = match (embedding, model) {
        (Embedding::Lm, Some(dir)) => Some(load_lm(&dir)?),
        (Embedding::Lm, None) => bail!("--embedding lm: give the frame model with --model DIR"),
        _ => None,
    };
    let metric = query::metric_or_default(metric.as_deref().unwrap_or(""))
        .map_err(|e| anyhow::anyhow!("--{e}"))?;
    let filters = parse_pairs("--filter", &filter)?;
    let m = io::read_path(&motion, &read.options())?.motion;
    let req = QueryRequest {
        source: m.into(),
        start_s: start,
        frames,
        k,
        embedding,
        metric,
        filters,
        exact,
        collections: None,
    };
    runtime()?.block_on(query(db, req, lm, json))
}

async fn ingest(
    paths: Vec<PathBuf>,
    db: PathBuf,
    opts: IngestOptions,
    lm: Option<choreo::lm::embed::LmEmbedder>,
    json: bool,
) -> Result<()> {
    if opts.hop == 0 {
        bail!("--hop must be at least 1");
    }
    let store = Store::open(&db).await?;
    if !choreo::service::auth::valid_collection_name(&opts.collection) {
        bail!("--collection: 1 to 64 letters, digits and - _ . only");
    }
    store.create_collection(&opts.collection).await?;
    let files = choreo::search::ingest::collect_files_with(&paths, &opts.read);
    let bar = indicatif::ProgressBar::new(files.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} files, {elapsed} elapsed, eta {eta} {msg}",
        )
        .expect("template"),
    );
    let progress = |done: usize, _total: usize, file: &str| {
        bar.set_position(done as u64);
        bar.set_message(file.rsplit('/').next().unwrap_or(file).to_string());
    };
    let report = choreo::search::ingest::ingest(&store, &paths, &opts, &progress).await?;
    bar.finish_and_clear();
    let lm_windows = match lm {
        Some(emb) => {
            let searcher = Searcher::open(store, HnswParams::default()).await?;
            searcher.set_lm(emb);
            Some(searcher.prepare_lm().await?)
        }
        None => None,
    };
    if json {
        let mut v = serde_json::to_value(&report)?;
        if let Some(n) = lm_windows {
            v["lm_windows"] = json!(n);
        }
        println!("{v}");
    } else {
        if let Some(n) = lm_windows {
            println!("lm vectors computed for {n} stored windows");
        }
        println!(
            "{} files: {} motions stored ({} windows), {} already stored, {} errors",
            report.files,
            report.motions,
            report.windows,
            report.skipped,
            report.errors.len()
        );
        for e in &report.errors {
            // Every reason starts with the file it is about.
            println!("  {}", e.reason);
        }
    }
    Ok(())
}

async fn query(
    db: PathBuf,
    req: QueryRequest,
    lm: Option<choreo::lm::embed::LmEmbedder>,
    json: bool,
) -> Result<()> {
    if !db.exists() {
        bail!("{}: no such store (run choreo ingest first)", db.display());
    }
    let store = Store::open(&db).await?;
    let searcher = std::sync::Arc::new(Searcher::open(store, HnswParams::default()).await?);
    if let Some(emb) = lm {
        searcher.set_lm(emb);
    }
    let (embedding, metric) = (req.embedding, req.metric);
    let hits = searcher.query(req).await?;
    if json {
        println!(
            "{}",
            json!({"embedding": embedding, "metric": metric, "hits": hits})
        );
    } else {
        println!("{:>4}  {:>8}  {:>8}  motion", "rank", "score", "start_s");
        for (i, h) in hits.iter().enumerate() {
            let labels: Vec<String> = h
                .labels
                .iter()
                .filter(|(k, _)| *k != "corpus")
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            let video = match (&h.video, h.video_time_s) {
                (Some(v), Some(t)) => format!("  video {v} at {t:.2} s"),
                _ => String::new(),
            };
            println!(
                "{:>4}  {:>8.4}  {:>8.2}  {}  {}{video}",
                i + 1,
                h.score,
                h.start_s,
                h.source_path,
                labels.join(" ")
            );
        }
    }
    Ok(())
}
