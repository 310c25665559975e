//! `choreo`: the command-line front of the library (and, later, the server).

mod cli;

/// mimalloc with a counter of allocations, for the allocations-per-token
/// figure of `choreo bench model` (one relaxed atomic add per allocation).
mod choreo_alloc {
    use mimalloc::MiMalloc as System;
    use std::alloc::{GlobalAlloc, Layout};
    use std::sync::atomic::{AtomicU64, Ordering};

    static ALLOCS: AtomicU64 = AtomicU64::new(0);

    pub struct Counting;

    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
            System.alloc(l)
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            System.dealloc(p, l)
        }
        unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
            System.alloc_zeroed(l)
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
            System.realloc(p, l, n)
        }
    }

    /// Allocations so far (all threads).
    pub fn count() -> u64 {
        ALLOCS.load(Ordering::Relaxed)
    }
}

#[global_allocator]
static GLOBAL: choreo_alloc::Counting = choreo_alloc::Counting;

use anyhow::{bail, Context, Result};
use choreo::features::Embedding;
use choreo::index::hnsw::HnswParams;
use choreo::index::Metric;
use choreo::motion::io::{self, bvh, Format, ReadOptions};
use choreo::motion::retarget::{retarget_to_smpl13, JointMap};
use choreo::motion::rotation::*;
use choreo::motion::Motion;
use choreo::service::eval_query as eval_q;
use choreo::service::ingest::IngestOptions;
use choreo::service::query::{QueryRequest, Searcher};
use choreo::store::Store;
use clap::{Parser, Subcommand, ValueEnum};
use cli::write_npy_f32;
use serde_json::json;
use std::collections::BTreeMap;
use std::io::Read;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "choreo",
    version,
    about = "Search, transform, generate and classify human motion capture"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq)]
enum Joints {
    /// The SMPL 24-joint skeleton.
    Smpl24,
    /// The 13 joints of thesis 000 Table A.1 (retargets non-SMPL input).
    Smpl13,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Unit {
    M,
    Cm,
    Mm,
}

impl Unit {
    fn metres(self) -> f64 {
        match self {
            Unit::M => 1.0,
            Unit::Cm => 0.01,
            Unit::Mm => 0.001,
        }
    }
}

#[derive(clap::Args, Clone)]
struct ReadArgs {
    /// Metres per BVH file unit (detected from the skeleton's size if absent;
    /// e.g. 0.0254 for inches).
    #[arg(long, env = "CHOREO_BVH_SCALE")]
    bvh_scale: Option<f64>,
    /// Keypoint layout of a `.npy` or keypoint `.json` from a video pose
    /// estimator: h36m17 (MotionBERT, VideoPose3D) or mediapipe33.
    #[arg(long)]
    keypoints: Option<choreo::motion::keypoints::Layout>,
    /// Frame rate of a file that carries none (keypoint `.npy`, SMPL
    /// parameters from video); overrides a keypoint JSON's own.
    #[arg(long)]
    source_fps: Option<f64>,
    /// The file's up axis (y, -y, z, -z, x, -x) where it is not the
    /// format's own (keypoints: -y; WHAM world output: y).
    #[arg(long, allow_hyphen_values = true)]
    up: Option<choreo::motion::keypoints::Up>,
    /// Keypoint confidence below which a frame is flagged and bridged.
    #[arg(long)]
    min_confidence: Option<f64>,
    /// Keypoint smoothing before the solve: Gaussian σ in seconds (0 = off).
    #[arg(long)]
    smooth: Option<f64>,
}

/// `--fps` for commands that only read (inspect, ingest, query): the
/// frame rate of a file that carries none, as `--source-fps` (which
/// `convert` needs, its `--fps` being the output's).
#[derive(clap::Args, Clone)]
struct SourceFps {
    /// Frame rate of a keypoint `.npy` or SMPL-from-video file (the same as
    /// --source-fps).
    #[arg(long)]
    fps: Option<f64>,
}

impl ReadArgs {
    /// These options with `--fps` folded into `--source-fps`.
    fn with_fps(mut self, f: &SourceFps) -> Result<ReadArgs> {
        match (self.source_fps, f.fps) {
            (Some(a), Some(b)) if a != b => {
                bail!("--fps {b} and --source-fps {a} disagree: give one")
            }
            (None, Some(b)) => self.source_fps = Some(b),
            _ => {}
        }
        Ok(self)
    }

    fn options(&self) -> ReadOptions {
        ReadOptions {
            bvh: bvh::BvhReadOptions {
                metres_per_unit: self.bvh_scale,
            },
            keypoints: self.keypoints,
            fps: self.source_fps,
            up: self.up,
            min_confidence: self.min_confidence,
            smooth_s: self.smooth,
        }
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// Print what a motion file holds: format, fps, frames, joints, duration, labels.
    Inspect {
        file: PathBuf,
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        read: ReadArgs,
        #[command(flatten)]
        fps: SourceFps,
    },
    /// Convert between formats (.bvh or AMASS .npz out), optionally resampled,
    /// cut, mirrored, root-normalised or reduced/retargeted to 13 joints.
    Convert {
        input: PathBuf,
        output: PathBuf,
        /// Resample to this frame rate (SLERP rotations, lerp translation).
        #[arg(long)]
        fps: Option<f64>,
        /// Joint set of the output; non-SMPL input is retargeted.
        #[arg(long, value_enum)]
        joints: Option<Joints>,
        /// JSON object mapping SMPL joint names to source joint names, for retargeting.
        #[arg(long)]
        joint_map: Option<PathBuf>,
        /// Mirror left and right.
        #[arg(long)]
        mirror: bool,
        /// Start at the origin facing +z.
        #[arg(long)]
        normalize_root: bool,
        /// Keep frames START:END (after resampling), END exclusive.
        #[arg(long, value_parser = parse_range)]
        frames: Option<(usize, usize)>,
        /// Unit of BVH output.
        #[arg(long, value_enum, default_value = "cm")]
        out_unit: Unit,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Forward kinematics: joint positions in metres as JSON
    /// `{joints: [names], fps, positions: [frame][joint][xyz]}`.
    Positions {
        file: PathBuf,
        #[arg(long, value_parser = parse_range)]
        frames: Option<(usize, usize)>,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Add motion files/folders (any supported format) to a store: windows,
    /// embeddings, PCA refit. Idempotent (same content hash → skipped).
    Ingest {
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        #[arg(long, env = "CHOREO_DB", default_value = "choreo.db")]
        db: PathBuf,
        /// Window hop in frames at 60 fps.
        #[arg(long, default_value_t = 32)]
        hop: usize,
        /// KIND=VALUE added to every motion ingested now (repeatable).
        #[arg(long)]
        label: Vec<String>,
        /// Keep each file's bytes in the database, so `get` / `export`
        /// work after the files move (the store grows by their size).
        #[arg(long)]
        keep_files: bool,
        /// The footage the (single) file was estimated from, a path or URL:
        /// query hits then give the video time of each match.
        #[arg(long)]
        video: Option<String>,
        /// Video time of the file's first frame, seconds.
        #[arg(long, requires = "video", allow_hyphen_values = true)]
        video_offset: Option<f64>,
        /// The collection the motions go into (created if missing; the
        /// command line has the whole store).
        #[arg(long, default_value = "default")]
        collection: String,
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        read: ReadArgs,
        #[command(flatten)]
        fps: SourceFps,
    },
    /// The stored windows most like a segment of a motion file.
    Query {
        #[arg(long, env = "CHOREO_DB", default_value = "choreo.db")]
        db: PathBuf,
        #[arg(long)]
        motion: PathBuf,
        /// Segment start, seconds.
        #[arg(long, default_value_t = 0.0)]
        start: f64,
        /// Segment length in frames at 60 fps (at least 128).
        #[arg(long, default_value_t = 128)]
        frames: usize,
        #[arg(long, default_value_t = 10)]
        k: usize,
        /// stft, dct, pca or pose (default: pose for keypoint / SMPL-from-video
        /// files, i.e. with --keypoints or --source-fps; dct otherwise).
        #[arg(long)]
        embedding: Option<String>,
        #[arg(long, default_value = "cosine")]
        metric: String,
        /// KIND=VALUE, repeatable: hits must carry every label.
        #[arg(long)]
        filter: Vec<String>,
        /// Exact search instead of HNSW.
        #[arg(long)]
        exact: bool,
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        read: ReadArgs,
        #[command(flatten)]
        fps: SourceFps,
    },
    /// Move INPUT's low-frequency features toward TARGET's by gradient
    /// descent (Adam) and write the result (thesis 000 §3.5).
    Interpolate {
        #[arg(long)]
        input: PathBuf,
        #[arg(long)]
        target: PathBuf,
        /// Band [LO, HI) in coefficients of a 128-frame DCT (0:8 = 0–1.875 Hz).
        #[arg(long, default_value = "0:8", value_parser = parse_range)]
        band: (usize, usize),
        #[arg(long, default_value = "dct")]
        objective: String,
        #[arg(long, default_value_t = 300)]
        steps: usize,
        #[arg(long, default_value_t = 0.02)]
        lr: f64,
        #[arg(long)]
        out: PathBuf,
        /// Repair short capture glitches first (per joint: jumps > 45° that
        /// come back within 3 frames, replaced by SLERP).
        #[arg(long)]
        despike: bool,
        #[arg(long)]
        json: bool,
    },
    /// Zero every DCT coefficient at or above CUTOFF (128-frame units) along time.
    Lowpass {
        input: PathBuf,
        #[arg(long)]
        cutoff: usize,
        #[arg(long)]
        out: PathBuf,
    },
    /// Pick keyframes (first and last always kept) and rebuild the
    /// in-betweens; the clip is taken as SMPL-24 at 60 fps.
    Keyframes {
        #[arg(long)]
        motion: PathBuf,
        /// A metronome at this tempo stands for the music (onset selection).
        #[arg(long)]
        bpm: Option<f64>,
        /// Music file (WAV/Ogg/MP3) for onset selection.
        #[arg(long, conflicts_with = "bpm")]
        music: Option<PathBuf>,
        #[arg(long)]
        count: usize,
        /// even | onset | percussive | nmfd | dp
        #[arg(long, default_value = "dp")]
        select: String,
        /// slerp | bezier | learned
        #[arg(long, default_value = "slerp")]
        inbetween: String,
        /// The learned in-betweener (a folder written by `choreo-train
        /// inbetween`), for `--inbetween learned`.
        #[arg(long, env = "CHOREO_INBETWEENER", default_value = "models/inbetween")]
        inbetweener: PathBuf,
        #[arg(long)]
        out: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Serve REST and gRPC (see README: API).
    Serve(choreo::server::ServeConfig),
    /// Token file lines for `serve --tokens`: new random tokens, hashes.
    Token {
        #[command(subcommand)]
        cmd: cli::token::TokenCmd,
    },
    /// Rehearsal footage: keypoint and SMPL test files made from real takes.
    Footage {
        #[command(subcommand)]
        cmd: cli::footage::FootageCmd,
    },
    /// Benchmarks whose figures go to bench/RESULTS.md.
    Bench {
        #[command(subcommand)]
        cmd: BenchCmd,
    },
    /// Evaluations that reproduce the theses' tables.
    Eval {
        #[command(subcommand)]
        cmd: EvalCmd,
    },
    /// Internal checks used by the reference scripts.
    #[command(hide = true)]
    Dev {
        #[command(subcommand)]
        cmd: DevCmd,
    },
}

#[derive(Subcommand)]
enum BenchCmd {
    /// Exact vs HNSW on synthetic vectors (16-d latent lifted to --dim):
    /// build time, query latency p50/p95, QPS, recall@10 against exact.
    Index {
        #[arg(long, value_delimiter = ',', default_value = "10000,100000")]
        sizes: Vec<usize>,
        #[arg(long, default_value_t = 1152)]
        dim: usize,
        #[arg(long, default_value_t = 200)]
        queries: usize,
        #[arg(long, default_value = "cosine")]
        metric: String,
        /// Also write base_N.npy, queries.npy and gt_N.npy (exact top-10
        /// ids) here, for scripts/bench_faiss.py.
        #[arg(long)]
        dump: Option<PathBuf>,
        #[arg(long, default_value_t = 128)]
        ef_search: usize,
        /// Links per node (M).
        #[arg(long, default_value_t = 24)]
        m: usize,
        #[arg(long, default_value_t = 200)]
        ef_construction: usize,
        /// With --dump: write the vectors and the exact top-10 only, without
        /// building choreo's HNSW (for FAISS at sizes where that build takes
        /// most of an hour).
        #[arg(long, requires = "dump")]
        dump_only: bool,
        /// Besides --ef-search: also the smallest efSearch whose recall@10
        /// on these queries reaches this (0 = off), as FAISS's side of
        /// scripts/bench_index.sh is run.
        #[arg(long, default_value_t = 0.99)]
        target_recall: f64,
        /// HNSW graphs to build and measure: hnsw_rs, flat, or both.
        #[arg(long, value_delimiter = ',', default_value = "hnsw_rs,flat")]
        backend: Vec<String>,
    },
    /// DP keyframe selection time on a clip looped to --frames frames (60 fps):
    /// per 4/4 measure at --bpm, and over the whole clip (exact).
    Keyframes {
        #[arg(long)]
        motion: PathBuf,
        #[arg(long, default_value_t = 3600)]
        frames: usize,
        #[arg(long, default_value_t = 120.0)]
        bpm: f64,
        #[arg(long, default_value_t = 9)]
        per_measure: usize,
    },
    /// The exported language model in tract: whole-window forward
    /// tokens/s, incremental generation per-frame latency and real-time
    /// factor at the model's frame rate.
    Model {
        #[arg(long, default_value = "models/default")]
        model: PathBuf,
        #[arg(long, default_value_t = 20)]
        repeats: usize,
        /// Frames to generate for the streaming figures.
        #[arg(long, default_value_t = 200)]
        frames: usize,
        /// Write the benchmark window's inputs as JSON (for
        /// scripts/bench_onnxruntime.py).
        #[arg(long)]
        dump: Option<PathBuf>,
        /// The runtime to measure: tract or ort (a build with the
        /// `onnxruntime` feature, and --ort-lib or ORT_DYLIB_PATH).
        #[arg(long, default_value = "tract")]
        runtime: choreo::lm::engine::Runtime,
        #[arg(long)]
        ort_lib: Option<PathBuf>,
        /// Print one JSON object on one line.
        #[arg(long)]
        json: bool,
    },
    /// Ingest speed of keypoints from video: one long keypoint file (an
    /// hour at 30 fps by default) made from real takes, read + IK alone and
    /// ingested into a fresh store.
    Footage(cli::footage::BenchArgs),
    /// Embedding throughput (windows/s) on the real windows of a corpus.
    Embed {
        #[arg(long)]
        data: Vec<PathBuf>,
        /// Write the windows as windows.npy here (for scripts/bench_embed.py).
        #[arg(long)]
        dump: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum EvalCmd {
    /// Generated motion against held-out real clips of each label: FID_k,
    /// FID_g, acceleration / jerk / skating ratios, frozen fraction,
    /// diversity and conditioning accuracy (an LDA judge fitted on real
    /// training windows), one row per sampling setting.
    Generate {
        #[arg(long, default_value = "models/default")]
        model: PathBuf,
        /// A folder of clips (the trainer's split: the first 10 % by name
        /// hash are held out).
        #[arg(long)]
        data: PathBuf,
        /// The label kind to condition on (e.g. genre, style).
        #[arg(long)]
        labels: String,
        #[arg(long, default_value_t = 3)]
        per_label: usize,
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Sampling settings, T:K:P (temperature:top_k:top_p) or greedy.
        #[arg(long, value_delimiter = ',', default_values_t = ["greedy", "1:0:1", "0.9:0:0.95", "0.8:0:0.9"].map(String::from).to_vec())]
        sampling: Vec<String>,
        #[arg(long)]
        json: bool,
    },
    /// Keypoints from video: IK accuracy per joint (clean and noisy
    /// keypoints made from real takes, rest pose beside) and cross-modal
    /// search recall (keypoint versions against the mocap, both ways).
    Footage(cli::footage::EvalArgs),
    /// Thesis 000 Table 3.2 protocol on a corpus: every window a query,
    /// same-sequence neighbours excluded (or, --same-sequence allow, the
    /// thesis's own protocol), k = 10, majority vote, entropy (bans), and
    /// the majority class beside.
    Query {
        #[arg(long)]
        data: Vec<PathBuf>,
        /// Label kinds to score, comma-separated (e.g. content,style or genre,dancer).
        #[arg(long, value_delimiter = ',', required = true)]
        labels: Vec<String>,
        /// Embeddings to evaluate (default: all three).
        #[arg(long, value_delimiter = ',')]
        embedding: Vec<String>,
        #[arg(long, default_value_t = 32)]
        hop: usize,
        #[arg(long, default_value_t = 10)]
        k: usize,
        /// exclude: no neighbour from the query's own sequence (strict);
        /// allow: any window but the query itself (the thesis's protocol).
        #[arg(long, default_value = "exclude")]
        same_sequence: eval_q::SameSequence,
        #[arg(long)]
        json: bool,
    },
    /// Thesis 000 Tables 3.3/3.4 over pairs drawn from a corpus (fixed seed):
    /// every objective, cosine similarities of STFT embeddings, jitter.
    Interpolate {
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        #[arg(long, default_value_t = 10)]
        pairs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "0:8", value_parser = parse_range)]
        band: (usize, usize),
        #[arg(long, default_value_t = 300)]
        steps: usize,
        #[arg(long, default_value_t = 0.02)]
        lr: f64,
        /// Repair short capture glitches first (see `interpolate --despike`).
        #[arg(long)]
        despike: bool,
        #[arg(long)]
        json: bool,
    },
    /// Thesis 001 Tables 4.1–4.7 protocol: clips cut into 4/4 measures at
    /// their tempo, N keyframes per measure, MSE / FID_k / FID_g.
    Keyframes {
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Tempo for clips without a tempo label.
        #[arg(long, default_value_t = 120.0)]
        bpm: f64,
        #[arg(long, value_delimiter = ',', default_value = "3,5,9")]
        counts: Vec<usize>,
        #[arg(long)]
        json: bool,
    },
    /// Thesis 000 Tables 4.1, 4.2 and Figure 4.5 on each --data path (its own
    /// corpus): word length, compression, seconds in 1,024 tokens, geodesic
    /// error, for the uniform, quantile and JPEG-like tile codecs.
    Tokenize {
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Write Figure 4.5 (error vs uniform bins) here as PNG.
        #[arg(long)]
        plot: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum DevCmd {
    /// Print the window (channel-major), STFT, DCT and (fitted on the given
    /// files' windows) PCA of one window of a motion, as JSON.
    Features {
        #[arg(long)]
        motion: PathBuf,
        #[arg(long, default_value_t = 0)]
        start: usize,
        /// Files whose windows (hop 32) the PCA is fitted on.
        #[arg(long)]
        pca_on: Vec<PathBuf>,
    },
    /// Decode and analyse a music file; write the 30,720 Hz mono samples
    /// (y.npy, float32) and the features (features.json) into --out.
    Audio {
        #[arg(long)]
        music: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// Read `{"quats": [[w,x,y,z]...], "orders": ["ZXY", "xyz", ...]}` on stdin;
    /// print every conversion as JSON.
    Rotations,
}

fn parse_range(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s.split_once(':').ok_or("expected START:END")?;
    let a: usize = a
        .parse()
        .map_err(|_| format!("'{a}' is not a frame index"))?;
    let b: usize = b
        .parse()
        .map_err(|_| format!("'{b}' is not a frame index"))?;
    if a >= b {
        return Err(format!("{a}:{b} is empty"));
    }
    Ok((a, b))
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Inspect {
            file,
            json,
            read,
            fps,
        } => inspect(&file, json, &read.with_fps(&fps)?),
        Cmd::Convert {
            input,
            output,
            fps,
            joints,
            joint_map,
            mirror,
            normalize_root,
            frames,
            out_unit,
            read,
        } => {
            let loaded = io::read_path(&input, &read.options())?;
            let layout = loaded.bvh_layout.clone();
            let mut m = loaded.motion;
            let mut same_skeleton = true;
            if let Some(j) = joints {
                m = to_joints(m, j, joint_map.as_deref())?;
                same_skeleton = false;
            }
            if let Some(f) = fps {
                m = m.resample(f)?;
            }
            if let Some((a, b)) = frames {
                m = m.cut(a, b.min(m.frames()))?;
            }
            if mirror {
                m = m.mirror()?;
            }
            if normalize_root {
                m = m.normalize_root()?;
            }
            let opts = bvh::BvhWriteOptions {
                metres_per_unit: out_unit.metres(),
                layout: if same_skeleton { layout.as_ref() } else { None },
                ..Default::default()
            };
            io::write_path(&m, &output, &opts)?;
            eprintln!(
                "wrote {} ({} frames at {} fps, {} joints)",
                output.display(),
                m.frames(),
                m.fps,
                m.joints()
            );
            Ok(())
        }
        Cmd::Positions { file, frames, read } => {
            let mut m = io::read_path(&file, &read.options())?.motion;
            if let Some((a, b)) = frames {
                m = m.cut(a, b.min(m.frames()))?;
            }
            let pos = m.positions();
            let j = m.joints();
            let frames: Vec<Vec<Vec3>> = (0..m.frames())
                .map(|f| pos[f * j..(f + 1) * j].to_vec())
                .collect();
            println!(
                "{}",
                json!({"joints": m.skeleton.names, "fps": m.fps, "positions": frames})
            );
            Ok(())
        }
        Cmd::Dev {
            cmd: DevCmd::Rotations,
        } => dev_rotations(),
        Cmd::Dev {
            cmd: DevCmd::Audio { music, out },
        } => {
            let a = choreo::audio::read(&music)?;
            let t = std::time::Instant::now();
            let (y, f) = choreo::audio::analyse(&a, &music.display().to_string())?;
            let seconds = t.elapsed().as_secs_f64();
            std::fs::create_dir_all(&out)?;
            let arr = io::npy::NdArray {
                shape: vec![y.len()],
                data: y.iter().map(|&v| v as f64).collect(),
            };
            std::fs::write(out.join("y.npy"), arr.to_npy(true))?;
            let mut v = serde_json::to_value(&f)?;
            v["analysis_seconds"] = json!(seconds);
            std::fs::write(out.join("features.json"), v.to_string())?;
            eprintln!(
                "{}: {:.1} s of audio at {} Hz ({} ch) → {} frames, {} onset peaks, {} percussive peaks, analysed in {seconds:.2} s",
                music.display(),
                f.seconds,
                f.source_rate,
                f.channels,
                f.frames,
                f.peaks.len(),
                f.percussive_peaks.len()
            );
            Ok(())
        }
        Cmd::Dev {
            cmd:
                DevCmd::Features {
                    motion,
                    start,
                    pca_on,
                },
        } => dev_features(&motion, start, &pca_on),
        Cmd::Ingest {
            paths,
            db,
            hop,
            label,
            keep_files,
            video,
            video_offset,
            collection,
            json,
            read,
            fps,
        } => {
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
            runtime()?.block_on(ingest(paths, db, opts, json))
        }
        Cmd::Query {
            db,
            motion,
            start,
            frames,
            k,
            embedding,
            metric,
            filter,
            exact,
            json,
            read,
            fps,
        } => {
            let read = read.with_fps(&fps)?;
            let footage = read.keypoints.is_some() || read.source_fps.is_some();
            let embedding =
                embedding.unwrap_or_else(|| if footage { "pose" } else { "dct" }.into());
            let embedding = Embedding::parse(&embedding).with_context(|| {
                format!("--embedding: '{embedding}' is not stft, dct, pca or pose")
            })?;
            let metric = Metric::parse(&metric)
                .with_context(|| format!("--metric: '{metric}' is not cosine or euclidean"))?;
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
            runtime()?.block_on(query(db, req, json))
        }
        Cmd::Interpolate {
            input,
            target,
            band,
            objective,
            steps,
            lr,
            out,
            despike,
            json,
        } => {
            let objective = Embedding::parse(&objective)
                .with_context(|| format!("--objective: '{objective}' is not dct, stft or pca"))?;
            interpolate_cmd(
                &input, &target, band, objective, steps, lr, &out, despike, json,
            )
        }
        Cmd::Lowpass { input, cutoff, out } => {
            use choreo::features::interpolate::{lowpass, to_f64};
            use choreo::features::{rows72, smpl24_at_60};
            let m = smpl24_at_60(&io::read_path(&input, &ReadOptions::default())?.motion)?;
            let filtered = lowpass(&to_f64(&rows72(&m)), cutoff).map_err(|e| e.in_file(&m.name))?;
            let result = choreo::service::interpolate::with_channels(&m, &filtered);
            io::write_path(&result, &out, &bvh::BvhWriteOptions::default())?;
            eprintln!(
                "wrote {} ({} frames at 60 fps)",
                out.display(),
                result.frames()
            );
            Ok(())
        }
        Cmd::Bench {
            cmd:
                BenchCmd::Index {
                    sizes,
                    dim,
                    queries,
                    metric,
                    dump,
                    ef_search,
                    m,
                    ef_construction,
                    dump_only,
                    target_recall,
                    backend,
                },
        } => {
            let metric = Metric::parse(&metric).with_context(|| format!("--metric: '{metric}'"))?;
            let params = HnswParams {
                m,
                ef_construction,
                ef_search,
                ..Default::default()
            };
            let backends = backend
                .iter()
                .map(|b| {
                    choreo::index::hnsw::Backend::parse(b)
                        .with_context(|| format!("--backend: '{b}' is not hnsw_rs or flat"))
                })
                .collect::<Result<Vec<_>>>()?;
            cli::bench_index::run(&cli::bench_index::Bench {
                sizes,
                dim,
                queries,
                metric,
                dump,
                params,
                dump_only,
                target_recall,
                backends,
            })
        }
        Cmd::Bench {
            cmd: BenchCmd::Embed { data, dump },
        } => bench_embed(&data, dump.as_deref()),
        Cmd::Bench {
            cmd: BenchCmd::Footage(a),
        } => cli::footage::bench(a),
        Cmd::Eval {
            cmd: EvalCmd::Footage(a),
        } => cli::footage::eval(a),
        Cmd::Footage { cmd } => cli::footage::run(cmd),
        Cmd::Token { cmd } => cli::token::run(cmd),
        Cmd::Bench {
            cmd:
                BenchCmd::Model {
                    model,
                    repeats,
                    frames,
                    dump,
                    runtime,
                    ort_lib,
                    json,
                },
        } => {
            let engine = choreo::lm::engine::Engine::new(runtime, ort_lib.as_deref())?;
            cli::bench_model::run(&model, &engine, repeats, frames, dump.as_deref(), json)
        }
        Cmd::Bench {
            cmd:
                BenchCmd::Keyframes {
                    motion,
                    frames,
                    bpm,
                    per_measure,
                },
        } => bench_keyframes(&motion, frames, bpm, per_measure),
        Cmd::Eval {
            cmd:
                EvalCmd::Query {
                    data,
                    labels,
                    embedding,
                    hop,
                    k,
                    same_sequence,
                    json,
                },
        } => eval_query(data, labels, embedding, hop, k, same_sequence, json),
        Cmd::Eval {
            cmd: EvalCmd::Tokenize { data, plot, json },
        } => eval_tokenize(data, plot, json),
        Cmd::Eval {
            cmd:
                EvalCmd::Generate {
                    model,
                    data,
                    labels,
                    per_label,
                    seconds,
                    sampling,
                    json,
                },
        } => cli::eval_generate::run(&model, &data, &labels, per_label, seconds, &sampling, json),
        Cmd::Eval {
            cmd:
                EvalCmd::Keyframes {
                    data,
                    bpm,
                    counts,
                    json,
                },
        } => eval_keyframes(data, bpm, counts, json),
        Cmd::Serve(cfg) => {
            choreo::server::init_logging(cfg.log_format);
            runtime()?.block_on(choreo::server::serve(cfg))
        }
        Cmd::Keyframes {
            motion,
            bpm,
            music,
            count,
            select,
            inbetween,
            inbetweener,
            out,
            json,
        } => keyframes_cmd(
            motion,
            bpm,
            music,
            count,
            select,
            inbetween,
            &inbetweener,
            out,
            json,
        ),
        Cmd::Eval {
            cmd:
                EvalCmd::Interpolate {
                    data,
                    pairs,
                    seed,
                    band,
                    steps,
                    lr,
                    despike,
                    json,
                },
        } => eval_interpolate(data, pairs, seed, band, steps, lr, despike, json),
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}

fn parse_pairs(flag: &str, items: &[String]) -> Result<Vec<(String, String)>> {
    items
        .iter()
        .map(|f| {
            f.split_once('=')
                .filter(|(a, b)| !a.is_empty() && !b.is_empty())
                .map(|(a, b)| (a.to_string(), b.to_string()))
                .with_context(|| format!("{flag}: '{f}' is not KIND=VALUE"))
        })
        .collect()
}

async fn ingest(paths: Vec<PathBuf>, db: PathBuf, opts: IngestOptions, json: bool) -> Result<()> {
    if opts.hop == 0 {
        bail!("--hop must be at least 1");
    }
    let store = Store::open(&db).await?;
    if !choreo::api::auth::valid_collection_name(&opts.collection) {
        bail!("--collection: 1 to 64 letters, digits and - _ . only");
    }
    store.create_collection(&opts.collection).await?;
    let files = choreo::service::ingest::collect_files_with(&paths, &opts.read);
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
    let report = choreo::service::ingest::ingest(&store, &paths, &opts, &progress).await?;
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
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

async fn query(db: PathBuf, req: QueryRequest, json: bool) -> Result<()> {
    if !db.exists() {
        bail!("{}: no such store (run choreo ingest first)", db.display());
    }
    let store = Store::open(&db).await?;
    let searcher = std::sync::Arc::new(Searcher::open(store, HnswParams::default()).await?);
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

fn eval_query(
    data: Vec<PathBuf>,
    labels: Vec<String>,
    embedding: Vec<String>,
    hop: usize,
    k: usize,
    same: eval_q::SameSequence,
    json: bool,
) -> Result<()> {
    if data.is_empty() {
        bail!("--data: give at least one folder or file");
    }
    let embeddings: Vec<Embedding> = if embedding.is_empty() {
        Embedding::ALL.to_vec()
    } else {
        embedding
            .iter()
            .map(|e| {
                Embedding::parse(e)
                    .with_context(|| format!("--embedding: '{e}' is not stft, dct or pca"))
            })
            .collect::<Result<_>>()?
    };
    let files = choreo::service::ingest::collect_files(&data);
    let t = std::time::Instant::now();
    let corpus = eval_q::build_corpus(&files, hop, &embeddings);
    if corpus.sequence.is_empty() {
        bail!(
            "no windows: none of {} files gave a 128-frame window",
            files.len()
        );
    }
    let rows = eval_q::evaluate_with(&corpus, &labels, k, same);
    let majority = eval_q::majority(&corpus, &labels);
    if json {
        let majority: Vec<_> = majority
            .iter()
            .map(|(l, a, n)| json!({"label": l, "accuracy": a, "windows": n}))
            .collect();
        println!(
            "{}",
            json!({"rows": rows, "majority": majority, "same_sequence": same, "sequences": corpus.sequences, "windows": corpus.sequence.len(), "errors": corpus.errors, "seconds": t.elapsed().as_secs_f64()})
        );
    } else {
        println!(
            "{} sequences, {} windows (128 frames at 60 fps, hop {hop}), k = {k}, same-sequence neighbours {}",
            corpus.sequences,
            corpus.sequence.len(),
            match same {
                eval_q::SameSequence::Exclude => "excluded",
                eval_q::SameSequence::Allow => "allowed (the query window itself excluded)",
            }
        );
        println!(
            "{:<6} {:<10} {:<12} {:>9} {:>13} {:>8}",
            "embed", "metric", "label", "accuracy", "entropy(ban)", "queries"
        );
        for r in &rows {
            println!(
                "{:<6} {:<10} {:<12} {:>8.1}% {:>13.3} {:>8}",
                r.embedding.name(),
                r.metric.name(),
                r.label,
                100.0 * r.accuracy,
                r.entropy_bans,
                r.queries
            );
        }
        for (l, a, n) in &majority {
            println!(
                "{:<6} {:<10} {:<12} {:>8.1}% {:>13} {:>8}",
                "majority",
                "",
                l,
                100.0 * a,
                "",
                n
            );
        }
        for e in &corpus.errors {
            println!("unreadable: {e}");
        }
    }
    Ok(())
}

/// An SMPL-24 motion with its rotations replaced by a `[frames][72]` matrix
/// (translation kept, cut to the matrix's length).
#[allow(clippy::too_many_arguments)]
fn interpolate_cmd(
    input: &std::path::Path,
    target: &std::path::Path,
    band: (usize, usize),
    objective: Embedding,
    steps: usize,
    lr: f64,
    out: &std::path::Path,
    despike: bool,
    as_json: bool,
) -> Result<()> {
    use choreo::features::interpolate::InterpolateOptions;
    let a = io::read_path(input, &ReadOptions::default())?.motion;
    let b = io::read_path(target, &ReadOptions::default())?.motion;
    let opts = InterpolateOptions {
        objective,
        band,
        steps,
        learning_rate: lr,
    };
    let (o, r) = choreo::service::interpolate::interpolate_motions(&a, &b, &opts, despike)?;
    io::write_path(&o, out, &bvh::BvhWriteOptions::default())?;
    let seconds = r.seconds;
    let report = serde_json::to_value(&r)?;
    if as_json {
        println!("{report}");
    } else {
        println!(
            "{}: O→T {:.4}, I→O {:.4}, I→T {:.4}; jerk input {:.1}, output {:.1} m/s³; loss {:.3e} → {:.3e} in {} steps, {:.2} s; wrote {}",
            objective.name(),
            report["similarity"]["o_t"].as_f64().unwrap_or(0.0),
            report["similarity"]["i_o"].as_f64().unwrap_or(0.0),
            report["similarity"]["i_t"].as_f64().unwrap_or(0.0),
            report["jitter"]["input"].as_f64().unwrap_or(0.0),
            report["jitter"]["output"].as_f64().unwrap_or(0.0),
            r.loss[0],
            r.loss[r.loss.len() - 1],
            r.steps,
            seconds,
            out.display()
        );
    }
    Ok(())
}

fn bench_embed(data: &[PathBuf], dump: Option<&std::path::Path>) -> Result<()> {
    use choreo::features::*;
    use std::time::Instant;
    let files = choreo::service::ingest::collect_files(data);
    let mut wins = Vec::new();
    for f in &files {
        let c = channels72(&io::read_path(f, &ReadOptions::default())?.motion)?;
        for s in window_starts(c.len(), 32) {
            wins.push(window(&c, s));
        }
    }
    if wins.is_empty() {
        bail!("no windows in {} files", files.len());
    }
    if let Some(d) = dump {
        std::fs::create_dir_all(d)?;
        write_npy_f32(&d.join("windows.npy"), &wins)?;
    }
    let ex = Extractor::new(StftParams::default())?;
    let mut out = serde_json::Map::new();
    for e in [Embedding::Stft, Embedding::Dct] {
        let t = Instant::now();
        let mut sink = 0.0f32;
        for w in &wins {
            sink += ex.embed(e, w, None)?[0];
        }
        let s = t.elapsed().as_secs_f64();
        out.insert(
            e.name().into(),
            json!({"windows_per_s": wins.len() as f64 / s, "seconds": s, "check": sink}),
        );
    }
    let t = Instant::now();
    let p = Pca::fit(wins.iter().map(|w| w.as_slice()))?;
    let fit_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut sink = 0.0f32;
    for w in &wins {
        sink += p.project_window(w)[0];
    }
    let s = t.elapsed().as_secs_f64();
    out.insert("pca".into(), json!({"fit_s": fit_s, "windows_per_s": wins.len() as f64 / s, "seconds": s, "check": sink}));
    println!(
        "{}",
        json!({"windows": wins.len(), "threads": 1, "results": out})
    );
    Ok(())
}

fn dev_features(motion: &std::path::Path, start: usize, pca_on: &[PathBuf]) -> Result<()> {
    use choreo::features::*;
    let m = io::read_path(motion, &ReadOptions::default())?.motion;
    let ch = channels72(&m)?;
    if start + WINDOW > ch.len() {
        bail!(
            "window {start}..{} past {} frames",
            start + WINDOW,
            ch.len()
        );
    }
    let w = window(&ch, start);
    let ex = Extractor::new(StftParams::default())?;
    let pca = if pca_on.is_empty() {
        None
    } else {
        let mut wins = Vec::new();
        for f in pca_on {
            let c = channels72(&io::read_path(f, &ReadOptions::default())?.motion)?;
            for s in window_starts(c.len(), 32) {
                wins.push(window(&c, s));
            }
        }
        Some(Pca::fit(wins.iter().map(|w| w.as_slice()))?)
    };
    println!(
        "{}",
        json!({
            "window": w,
            "stft": ex.stft(&w),
            "dct": ex.dct(&w),
            "dct_full": ex.dct_full(&w),
            "pose": ex.pose(&w),
            "pca": pca.as_ref().map(|p| json!({"mean": p.mean, "components": p.components, "explained_variance": p.explained_variance, "projection": p.project_window(&w)})),
        })
    );
    Ok(())
}

fn to_joints(m: Motion, j: Joints, joint_map: Option<&std::path::Path>) -> Result<Motion> {
    let kind = m.skeleton.kind.clone();
    let m13 = match kind.as_str() {
        "smpl24" if j == Joints::Smpl24 => return Ok(m),
        "smpl13" if j == Joints::Smpl13 => return Ok(m),
        "smpl24" => m.to_smpl13()?,
        "smpl13" => m,
        _ => {
            let overrides: BTreeMap<String, String> = match joint_map {
                Some(p) => serde_json::from_str(
                    &std::fs::read_to_string(p)
                        .with_context(|| format!("{}: cannot read joint map", p.display()))?,
                )
                .with_context(|| {
                    format!(
                        "{}: expected a JSON object of SMPL name -> source name",
                        p.display()
                    )
                })?,
                None => BTreeMap::new(),
            };
            let map = JointMap::resolve(&m.skeleton, &overrides).map_err(|e| e.in_file(&m.name))?;
            retarget_to_smpl13(&m, &map)?
        }
    };
    Ok(match j {
        Joints::Smpl13 => m13,
        Joints::Smpl24 => m13.smpl13_to_smpl24()?,
    })
}

fn inspect(file: &std::path::Path, as_json: bool, read: &ReadArgs) -> Result<()> {
    let loaded = io::read_path(file, &read.options())?;
    let m = &loaded.motion;
    let v = json!({
        "file": file.display().to_string(),
        "format": loaded.format.name(),
        "fps": m.fps,
        "frames": m.frames(),
        "joints": m.joints(),
        "skeleton": m.skeleton.kind,
        "duration_s": m.duration_s(),
        "labels": m.labels,
        "footage": loaded.footage,
    });
    if as_json {
        println!("{v}");
    } else {
        println!("file      {}", file.display());
        println!("format    {}", loaded.format.name());
        println!("fps       {}", m.fps);
        println!("frames    {}", m.frames());
        println!("joints    {} ({})", m.joints(), m.skeleton.kind);
        println!("duration  {:.3} s", m.duration_s());
        for (k, val) in &m.labels {
            println!("label     {k} = {val}");
        }
        if loaded.format == Format::Bvh {
            if let Some(l) = &loaded.bvh_layout {
                println!("unit      {} m per file unit", l.metres_per_unit);
            }
        }
        if let Some(f) = &loaded.footage {
            println!("source    {} (up {})", f.layout, f.up);
            if f.layout != "smpl" {
                println!(
                    "unit      {:.6} m per file unit (from bone lengths)",
                    f.metres_per_unit
                );
                println!(
                    "confidence {:.3} mean over good frames (threshold {})",
                    f.mean_confidence, f.min_confidence
                );
            }
            println!(
                "flagged   {} of {} frames, bridged by SLERP, in {} gaps",
                f.flagged_frames,
                f.frames,
                f.gaps.len()
            );
            if f.first_frame > 0 {
                println!("video     first frame is video frame {}", f.first_frame);
            }
        }
    }
    Ok(())
}

fn dev_rotations() -> Result<()> {
    let mut s = String::new();
    std::io::stdin().read_to_string(&mut s)?;
    let v: serde_json::Value = serde_json::from_str(&s)?;
    let quats: Vec<Quat> = serde_json::from_value(v["quats"].clone()).context("quats")?;
    let orders: Vec<String> = serde_json::from_value(v["orders"].clone()).context("orders")?;
    if quats.is_empty() {
        bail!("no quats");
    }
    let mut euler = serde_json::Map::new();
    let mut euler_back = serde_json::Map::new();
    for o in &orders {
        let order: EulerOrder = o.parse().map_err(anyhow::Error::msg)?;
        let e: Vec<Vec3> = quats.iter().map(|q| quat_to_euler(*q, order)).collect();
        let back: Vec<Quat> = e.iter().map(|a| euler_to_quat(*a, order)).collect();
        euler.insert(o.clone(), json!(e));
        euler_back.insert(o.clone(), json!(back));
    }
    let mats: Vec<Mat3> = quats.iter().map(|q| quat_to_mat(*q)).collect();
    let aa: Vec<Vec3> = quats.iter().map(|q| quat_to_axis_angle(*q)).collect();
    let out = json!({
        "matrix": mats,
        "axis_angle": aa,
        "quat_from_axis_angle": aa.iter().map(|a| axis_angle_to_quat(*a)).collect::<Vec<_>>(),
        "quat_from_matrix": mats.iter().map(mat_to_quat).collect::<Vec<_>>(),
        "sixd": mats.iter().map(mat_to_6d).collect::<Vec<_>>(),
        "matrix_from_sixd": mats.iter().map(|m| sixd_to_mat(&mat_to_6d(m))).collect::<Vec<_>>(),
        "euler": euler,
        "quat_from_euler": euler_back,
        "geodesic_next": quats.windows(2).map(|w| geodesic_quat(w[0], w[1])).collect::<Vec<_>>(),
    });
    println!("{out}");
    Ok(())
}

fn eval_tokenize(data: Vec<PathBuf>, plot: Option<PathBuf>, json: bool) -> Result<()> {
    use choreo::service::eval_tokenize as et;
    use choreo::tokenize::eval::CodecReport;
    let t = std::time::Instant::now();
    let corpora = data
        .iter()
        .map(|d| et::eval_corpus(d).with_context(|| format!("--data {}", d.display())))
        .collect::<Result<Vec<_>>>()?;
    if let Some(p) = &plot {
        let png = choreo::plot::render_png(&et::figure_4_5(&corpora), 960, 600);
        std::fs::write(p, png).with_context(|| format!("--plot {}", p.display()))?;
    }
    if json {
        println!(
            "{}",
            json!({"corpora": corpora, "seconds": t.elapsed().as_secs_f64()})
        );
        return Ok(());
    }
    let table = |title: &str, rows: &[CodecReport]| {
        println!("\n{title}");
        println!(
            "{:<28} {:>9} {:>8} {:>11} {:>9} {:>10} {:>9} {:>9}",
            "codec",
            "avg word",
            "max word",
            "compression",
            "s in 1024",
            "mean err°",
            "p99 err°",
            "max err°"
        );
        for r in rows {
            println!(
                "{:<28} {:>9.1} {:>8} {:>11.1} {:>9.2} {:>10.4} {:>9.2} {:>9.2}",
                r.codec,
                r.avg_word_length,
                r.max_word_length,
                r.compression_factor,
                r.seconds_in_1024,
                r.mean_error_rad.to_degrees(),
                r.p99_error_rad.to_degrees(),
                r.max_error_rad.to_degrees()
            );
        }
    };
    for c in &corpora {
        println!(
            "== {} — {} files ({} unreadable), {} frames at 60 fps, {} channels",
            c.tables.corpus,
            c.files,
            c.errors.len(),
            c.tables.frame_codecs.first().map(|r| r.frames).unwrap_or(0),
            c.tables.channels
        );
        table("Frame codecs (SMPL-24, 60 fps)", &c.tables.frame_codecs);
        table(
            "Model layout (SMPL-13, 20 fps, angles only)",
            &c.model_layout,
        );
        table(
            "Table 4.1 (10% kept, 24 components, 360 quantile bins)",
            &c.tables.table_4_1,
        );
        table(
            "Table 4.2 (60-frame tiles, PCA, 360 quantile bins)",
            &c.tables.table_4_2,
        );
        table("Figure 4.5 (uniform bins)", &c.tables.figure_4_5);
    }
    println!("\n{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn eval_interpolate(
    data: Vec<PathBuf>,
    pairs: usize,
    seed: u64,
    band: (usize, usize),
    steps: usize,
    lr: f64,
    despike: bool,
    json: bool,
) -> Result<()> {
    use choreo::features::interpolate::InterpolateOptions;
    let files = choreo::service::ingest::collect_files(&data);
    let base = InterpolateOptions {
        objective: Embedding::Dct,
        band,
        steps,
        learning_rate: lr,
    };
    let t = std::time::Instant::now();
    let r = choreo::service::interpolate::eval_interpolate(
        &files,
        pairs,
        seed,
        &Embedding::ALL,
        &base,
        despike,
    )?;
    if json {
        println!(
            "{}",
            json!({"rows": r.rows, "summary": r.summary, "files": r.files, "errors": r.errors, "seconds": t.elapsed().as_secs_f64()})
        );
        return Ok(());
    }
    println!(
        "{} pairs from {} files (seed {seed}), band {}:{}, {steps} Adam steps, lr {lr}, glitch repair {}",
        pairs.min(r.rows.len() / 3),
        r.files,
        band.0,
        band.1,
        if despike { "on" } else { "off" }
    );
    println!(
        "{:>4} {:<6} {:>7} {:>7} {:>7} {:>8} {:>9} {:>9} {:>9} {:>9}  input → target",
        "pair",
        "obj",
        "O→T",
        "I→O",
        "I→T",
        "between",
        "jerk in",
        "jerk swap",
        "jerk out",
        "med out"
    );
    let short = |s: &str| {
        std::path::Path::new(s)
            .file_stem()
            .map(|x| x.to_string_lossy().to_string())
            .unwrap_or_else(|| s.to_string())
    };
    for row in &r.rows {
        println!(
            "{:>4} {:<6} {:>7.3} {:>7.3} {:>7.3} {:>8} {:>9.0} {:>9.0} {:>9.0} {:>9.0}  {} → {}",
            row.pair,
            row.objective.name(),
            row.similarity.o_t,
            row.similarity.i_o,
            row.similarity.i_t,
            if row.between { "yes" } else { "no" },
            row.jitter.input,
            row.jitter.band_swap,
            row.jitter.output,
            row.jitter.median.output,
            short(&row.input),
            short(&row.target)
        );
    }
    println!("\nsummary (means over pairs; jerk in m/s³, 'band swap' = the input with its band replaced by the target's)");
    for s in &r.summary {
        println!(
            "{:<5} O→T {:.3}  I→O {:.3}  I→T {:.3}  between {}/{}  jerk input {:.0}, band swap {:.0}, output {:.0}; output/swap (medians) {:.2}",
            s.objective.name(),
            s.mean_o_t,
            s.mean_i_o,
            s.mean_i_t,
            s.between,
            s.pairs,
            s.mean_jerk_input,
            s.mean_jerk_band_swap,
            s.mean_jerk_output,
            s.median_jerk_ratio
        );
    }
    println!("{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn keyframes_cmd(
    motion: PathBuf,
    bpm: Option<f64>,
    music: Option<PathBuf>,
    count: usize,
    select: String,
    inbetween: String,
    inbetweener: &std::path::Path,
    out: Option<PathBuf>,
    json: bool,
) -> Result<()> {
    use choreo::service::keyframes::{
        reconstruct, Inbetween, KeyframeRequest, LearnedModel, Music, Select,
    };
    let select = Select::parse(&select).with_context(|| {
        format!("--select: '{select}' is not even, onset, percussive, nmfd or dp")
    })?;
    let inbetween = match inbetween.as_str() {
        "slerp" => Inbetween::Slerp,
        "bezier" => Inbetween::Bezier,
        "learned" => Inbetween::Learned(LearnedModel(std::sync::Arc::new(
            choreo::lm::inbetween::Inbetweener::load(inbetweener)
                .with_context(|| format!("--inbetweener {}", inbetweener.display()))?,
        ))),
        other => bail!("--inbetween: '{other}' is not slerp, bezier or learned"),
    };
    let music = match (music, bpm) {
        (Some(p), _) => {
            let a = choreo::audio::read(&p)?;
            let (_, f) = choreo::audio::analyse(&a, &p.display().to_string())?;
            Music::Audio(Box::new(f))
        }
        (None, Some(b)) => Music::Bpm(b),
        (None, None) => Music::None,
    };
    let m = io::read_path(&motion, &ReadOptions::default())?.motion;
    let req = KeyframeRequest {
        select,
        inbetween,
        count,
        music,
    };
    let (r, report) =
        reconstruct(&m, &req).map_err(|e| anyhow::anyhow!("{}: {e}", motion.display()))?;
    if let Some(o) = &out {
        io::write_path(&r, o, &bvh::BvhWriteOptions::default())?;
    }
    if json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "{} keyframes ({} / {}) of {} frames: {:?}\nMSE {:.4} cm²{}",
            report.keyframes.len(),
            report.select.name(),
            report.inbetween,
            report.frames,
            report.keyframes,
            report.mse * 1e4,
            out.map(|o| format!("; wrote {}", o.display()))
                .unwrap_or_default()
        );
        if let Some(b) = report.beat_alignment {
            println!(
                "beat alignment (σ = 3 frames), music→motion: original {:.3}, rebuilt {:.3}; motion→music: original {:.3}, rebuilt {:.3}",
                b.original_music_to_motion, b.rebuilt_music_to_motion, b.original_motion_to_music, b.rebuilt_motion_to_music
            );
        }
    }
    Ok(())
}

fn eval_keyframes(data: Vec<PathBuf>, bpm: f64, counts: Vec<usize>, json: bool) -> Result<()> {
    let files = choreo::service::ingest::collect_files(&data);
    let t = std::time::Instant::now();
    let r = choreo::service::keyframes::eval_keyframes(&files, bpm, &counts)?;
    if json {
        println!(
            "{}",
            json!({"rows": r.rows, "clips": r.clips, "errors": r.errors, "seconds": t.elapsed().as_secs_f64()})
        );
        return Ok(());
    }
    for c in &r.clips {
        println!(
            "{}: {} BPM{}, {} frames a measure, {} measures",
            c.name,
            c.bpm,
            if c.tempo_known { "" } else { " (assumed)" },
            c.frames_per_measure,
            c.measures
        );
    }
    let f = |v: Option<f64>| v.map(|x| format!("{x:.2}")).unwrap_or_else(|| "—".into());
    for &n in &counts {
        println!("\n{n} keyframes per measure");
        println!(
            "{:<8} {:<11} {:>9} {:>10} {:>10}",
            "select", "in-between", "MSE cm²", "FID_k", "FID_g"
        );
        for row in r.rows.iter().filter(|x| x.keyframes_per_measure == n) {
            println!(
                "{:<8} {:<11} {:>9.3} {:>10} {:>10}",
                row.select.name(),
                row.inbetween,
                row.mse_cm2,
                f(row.fid_k),
                f(row.fid_g)
            );
        }
    }
    println!("\n{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn bench_keyframes(
    motion: &std::path::Path,
    frames: usize,
    bpm: f64,
    per_measure: usize,
) -> Result<()> {
    use choreo::keyframes::{dp, frames_per_measure, position_curve, SegmentCost};
    let m =
        choreo::features::smpl24_at_60(&io::read_path(motion, &ReadOptions::default())?.motion)?;
    // Loop the clip (root translation continued) up to `frames`.
    let mut trans = vec![];
    let mut rots = vec![];
    let j = m.joints();
    let mut offset = [0.0; 3];
    while trans.len() < frames {
        for f in 0..m.frames() {
            if trans.len() == frames {
                break;
            }
            let t = m.trans[f];
            trans.push([t[0] + offset[0], t[1], t[2] + offset[2]]);
            rots.extend_from_slice(&m.rotations[f * j..(f + 1) * j]);
        }
        let last = m.trans[m.frames() - 1];
        offset = [
            offset[0] + last[0] - m.trans[0][0],
            0.0,
            offset[2] + last[2] - m.trans[0][2],
        ];
    }
    let long = m.with_data(trans, rots);
    let p = long.positions();
    let curve = position_curve(&p);
    let fpm = frames_per_measure(bpm, 60.0).round() as usize;
    let t = std::time::Instant::now();
    let mut measures = 0;
    let mut s = 0;
    while s + fpm < frames {
        let c = SegmentCost::new(curve[s * 3 * j..(s + fpm + 1) * 3 * j].to_vec(), 3 * j);
        dp(&c, per_measure, None)?;
        measures += 1;
        s += fpm;
    }
    let per = t.elapsed().as_secs_f64();
    let total_keys = measures * (per_measure - 1) + 1;
    let t = std::time::Instant::now();
    let c = SegmentCost::new(curve.clone(), 3 * j);
    let (_, cost) = dp(&c, total_keys, None)?;
    let whole = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let (_, cost_gap) = dp(&c, total_keys, Some(2 * fpm))?;
    let gapped = t.elapsed().as_secs_f64();
    println!(
        "{frames} frames ({} looped), {bpm} BPM = {fpm} frames a measure, {measures} measures\n\
         per measure, {per_measure} keyframes each: {:.3} s\n\
         whole clip, {total_keys} keyframes, exact: {:.2} s (cost {:.3})\n\
         whole clip, gaps ≤ 2 measures: {:.2} s (cost {:.3})",
        m.name, per, whole, cost, gapped, cost_gap
    );
    Ok(())
}
