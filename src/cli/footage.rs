//! Rehearsal footage on the command line: `choreo footage synth` (keypoint
//! and SMPL test files made from real takes), `choreo eval footage` (IK
//! accuracy and cross-modal search) and `choreo bench footage` (ingest
//! speed of an hour of keypoints).

use anyhow::{bail, Context, Result};
use choreo::eval::footage::{evaluate, FootageEvalOptions};
use choreo::features::Embedding;
use choreo::motion::io::{self, keypoints as kpio, smpl_params, ReadOptions};
use choreo::motion::keypoints::{synthesize, Layout, SynthOptions, DEFAULT_SMOOTH_S};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Subcommand)]
pub enum FootageCmd {
    /// Keypoints (or SMPL parameters) made from a real SMPL take, the way a
    /// video pose estimator would give them: forward kinematics, a camera
    /// (y down, z away), noise, per-point jitter, missed frames and
    /// low-confidence spells. OUT's extension picks the file: .npy
    /// (T, K, 3) keypoints, .json keypoint JSON, .npz WHAM-style SMPL
    /// parameters (missed frames left out of frame_ids).
    Synth {
        take: PathBuf,
        out: PathBuf,
        #[arg(long, default_value = "h36m17")]
        layout: Layout,
        /// Video frame rate of the output.
        #[arg(long, default_value_t = 30.0)]
        fps: f64,
        /// Clean keypoints: no noise, drops or low-confidence spells.
        #[arg(long)]
        clean: bool,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Camera heading about the vertical, degrees.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f64,
        /// File units per metre (1000: millimetres). Default: 1000 for
        /// noisy output, 1 for --clean.
        #[arg(long)]
        units_per_metre: Option<f64>,
    },
}

pub fn run(cmd: FootageCmd) -> Result<()> {
    match cmd {
        FootageCmd::Synth {
            take,
            out,
            layout,
            fps,
            clean,
            seed,
            yaw,
            units_per_metre,
        } => synth(&take, &out, layout, fps, clean, seed, yaw, units_per_metre),
    }
}

#[allow(clippy::too_many_arguments)]
fn synth(
    take: &Path,
    out: &Path,
    layout: Layout,
    fps: f64,
    clean: bool,
    seed: u64,
    yaw: f64,
    units: Option<f64>,
) -> Result<()> {
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        bail!("--fps: {fps} is not a frame rate");
    }
    let m = io::read_path(take, &ReadOptions::default())?.motion;
    let m = choreo::features::smpl24_at_60(&m)?;
    let mut o = if clean {
        SynthOptions::clean(layout, fps)
    } else {
        SynthOptions::noisy(layout, fps, seed)
    };
    o.yaw_deg = yaw;
    if let Some(u) = units {
        if !(u.is_finite() && u > 0.0) {
            bail!("--units-per-metre: {u} is not a positive number");
        }
        o.units_per_metre = u;
    }
    let lower = out.display().to_string().to_ascii_lowercase();
    let kp = synthesize(&m, &o)?;
    let bytes = if lower.ends_with(".npy") {
        kpio::write_npy(&kp)
    } else if lower.ends_with(".json") {
        kpio::write_json(&kp)
    } else if lower.ends_with(".npz") {
        // SMPL parameters: the take itself at the video rate, missed frames
        // left out of frame_ids.
        let v = m.resample(fps)?;
        let k = layout.len();
        let keep: Vec<usize> = (0..v.frames().min(kp.frames()))
            .filter(|&f| !kp.points[f * k][0].is_nan())
            .collect();
        smpl_params::write_npz(&v, &keep)?
    } else {
        bail!(
            "{}: the output must end in .npy, .json or .npz",
            out.display()
        );
    };
    std::fs::write(out, bytes).with_context(|| out.display().to_string())?;
    eprintln!(
        "wrote {} ({} frames at {fps} fps, {layout}, {})",
        out.display(),
        kp.frames(),
        if clean { "clean" } else { "noisy" }
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct EvalArgs {
    /// SMPL takes (files or folders): each is made into keypoints, solved
    /// back and searched for.
    #[arg(long, required = true)]
    data: Vec<PathBuf>,
    /// Leave out the first N files (sorted by name) of each folder: the
    /// hinge axes were measured on the first 40 AIST++-VRM dances.
    #[arg(long, default_value_t = 0)]
    skip: usize,
    /// Use at most N files per folder after --skip (0 = all).
    #[arg(long, default_value_t = 0)]
    limit: usize,
    #[arg(long, value_delimiter = ',', default_value = "h36m17,mediapipe33")]
    layouts: Vec<Layout>,
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Share of the torso's tilt given to the pelvis (default: each
    /// layout's own).
    #[arg(long)]
    pelvis_share: Option<f64>,
    /// Keypoint smoothing before the solve (Gaussian σ, seconds; 0 = off).
    #[arg(long, default_value_t = DEFAULT_SMOOTH_S)]
    smooth: f64,
    #[arg(long, value_delimiter = ',', default_value = "pose,dct,stft")]
    embedding: Vec<String>,
    #[arg(long, default_value_t = 32)]
    hop: usize,
    /// IK accuracy only (no search tables).
    #[arg(long)]
    ik_only: bool,
    #[arg(long)]
    json: bool,
}

/// The motion files of each path (folders sorted by name, then --skip /
/// --limit applied per folder).
fn takes(paths: &[PathBuf], skip: usize, limit: usize) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let files = choreo::data::files_with_ext(p, &["pkl", "npz", "bvh"]);
            let it = files.into_iter().skip(skip);
            if limit > 0 {
                out.extend(it.take(limit));
            } else {
                out.extend(it);
            }
        } else {
            out.push(p.clone());
        }
    }
    out
}

pub fn eval(a: EvalArgs) -> Result<()> {
    let embeddings = a
        .embedding
        .iter()
        .map(|e| {
            Embedding::parse(e)
                .with_context(|| format!("--embedding: '{e}' is not pose, stft or dct"))
        })
        .collect::<Result<Vec<_>>>()?;
    if embeddings.contains(&Embedding::Pca) {
        bail!("--embedding: pca needs a fitted basis; use dct or stft");
    }
    let files = takes(&a.data, a.skip, a.limit);
    if files.is_empty() {
        bail!("--data: no motion files");
    }
    let t0 = Instant::now();
    let r = evaluate(
        &files,
        &FootageEvalOptions {
            layouts: a.layouts,
            video_fps: a.fps,
            seed: a.seed,
            pelvis_share: a.pelvis_share,
            smooth_s: a.smooth,
            embeddings,
            hop: a.hop,
            ik_only: a.ik_only,
        },
    );
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    println!(
        "== {} takes, {} frames at 60 fps, keypoints at {} fps, pelvis share {}, smoothing σ {} s ({:.0} s)",
        r.takes,
        r.frames,
        r.video_fps,
        r.pelvis_share.map_or("each layout's".to_string(), |p| p.to_string()),
        r.smooth_s,
        t0.elapsed().as_secs_f64()
    );
    for e in &r.errors {
        println!("error: {e}");
    }
    println!(
        "\nIK error per SMPL-13 joint, degrees (twist about the joint's own bone excluded; \
              observable: the parent's twist excluded too, for knees and elbows)"
    );
    println!(
        "| layout | condition | measure | joint | median ° | p90 ° | frames |\n|---|---|---|---|---:|---:|---:|"
    );
    for row in &r.ik {
        let measure = match row.measure {
            choreo::motion::keypoints::Measure::Observable => "observable",
            choreo::motion::keypoints::Measure::ParentFrame => "parent frame",
        };
        println!(
            "| {} | {} | {measure} | {} | {:.2} | {:.2} | {} |",
            row.layout, row.condition, row.joint, row.median_deg, row.p90_deg, row.frames
        );
    }
    if !r.search.is_empty() {
        println!("\nCross-modal search (exact cosine; recall over distinct takes)");
        println!("| layout | keypoints | direction | embedding | queries | recall@1 | recall@10 | same moment@1 | chance@1 |\n|---|---|---|---|---:|---:|---:|---:|---:|");
        for s in &r.search {
            println!(
                "| {} | {} | {} | {} | {} | {:.1} % | {:.1} % | {:.1} % | {:.1} % |",
                s.layout,
                s.condition,
                s.direction,
                s.embedding.name(),
                s.queries,
                100.0 * s.recall_at_1,
                100.0 * s.recall_at_10,
                100.0 * s.same_moment_at_1,
                100.0 * s.chance_at_1
            );
        }
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct BenchArgs {
    /// SMPL takes to make the hour of keypoints from (looped).
    #[arg(long, required = true)]
    data: Vec<PathBuf>,
    #[arg(long, default_value = "h36m17")]
    layout: Layout,
    #[arg(long, default_value_t = 3600.0)]
    seconds: f64,
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
}

/// One long keypoint file (takes made into noisy keypoints and joined),
/// then: read + IK alone, and `choreo ingest` into a fresh SQLite store
/// (read, IK, windows, embeddings, insert, PCA fit).
pub fn bench(a: BenchArgs) -> Result<()> {
    let files = takes(&a.data, 0, 0);
    let want = (a.seconds * a.fps).round() as usize;
    let mut kp: Option<choreo::motion::keypoints::Keypoints> = None;
    let t0 = Instant::now();
    'outer: loop {
        for (i, f) in files.iter().enumerate() {
            let m =
                choreo::features::smpl24_at_60(&io::read_path(f, &ReadOptions::default())?.motion)?;
            let part = synthesize(&m, &SynthOptions::noisy(a.layout, a.fps, i as u64))?;
            match &mut kp {
                None => kp = Some(part),
                Some(k) => {
                    k.points.extend(part.points);
                    k.confidence.extend(part.confidence);
                }
            }
            if kp.as_ref().is_some_and(|k| k.frames() >= want) {
                break 'outer;
            }
        }
        if files.is_empty() {
            bail!("--data: no motion files");
        }
    }
    let mut kp = kp.expect("at least one take");
    let k = a.layout.len();
    kp.points.truncate(want * k);
    kp.confidence.truncate(want * k);
    let made = t0.elapsed().as_secs_f64();
    let dir = tempdir()?;
    let file = dir.join(format!("hour_{}.npy", a.layout));
    std::fs::write(&file, kpio::write_npy(&kp))?;
    let bytes = std::fs::metadata(&file)?.len();
    let read = ReadOptions {
        keypoints: Some(a.layout),
        fps: Some(a.fps),
        ..Default::default()
    };
    let t1 = Instant::now();
    let loaded = io::read_path(&file, &read)?;
    let solve_s = t1.elapsed().as_secs_f64();
    let flagged = loaded.footage.as_ref().map_or(0, |f| f.flagged_frames);
    drop(loaded);
    let db = dir.join("bench.db");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let t2 = Instant::now();
    let report = rt.block_on(async {
        let store = choreo::store::Store::open(&db).await?;
        let opts = choreo::search::ingest::IngestOptions {
            read: read.clone(),
            ..Default::default()
        };
        choreo::search::ingest::ingest(&store, std::slice::from_ref(&file), &opts, &|_, _, _| {})
            .await
    })?;
    let ingest_s = t2.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&dir);
    if !report.errors.is_empty() {
        bail!("ingest failed: {:?}", report.errors);
    }
    println!(
        "{}",
        serde_json::json!({
            "layout": a.layout,
            "frames": want,
            "fps": a.fps,
            "seconds_of_video": want as f64 / a.fps,
            "file_mb": bytes as f64 / 1e6,
            "flagged_frames": flagged,
            "make_s": made,
            "read_and_ik_s": solve_s,
            "ingest_s": ingest_s,
            "windows": report.windows,
            "ingest_s_per_video_hour": ingest_s * 3600.0 / (want as f64 / a.fps),
        })
    );
    Ok(())
}

fn tempdir() -> Result<PathBuf> {
    let d = std::env::temp_dir().join(format!("choreo-footage-{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}
