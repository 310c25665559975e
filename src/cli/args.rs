//! The command line's shape: the top-level commands and the options
//! several share.

use anyhow::{bail, Result};
use choreo::motion::io::{bvh, ReadOptions};
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(
    name = "choreo",
    version,
    about = "Search, transform, generate and classify human motion capture"
)]
pub struct Cli {
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq)]
pub enum Joints {
    /// The SMPL 24-joint skeleton.
    Smpl24,
    /// The 13 joints of thesis 000 Table A.1 (retargets non-SMPL input).
    Smpl13,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Unit {
    M,
    Cm,
    Mm,
}

impl Unit {
    pub fn metres(self) -> f64 {
        match self {
            Unit::M => 1.0,
            Unit::Cm => 0.01,
            Unit::Mm => 0.001,
        }
    }
}

#[derive(clap::Args, Clone)]
pub struct ReadArgs {
    /// Metres per BVH file unit (detected from the skeleton's size if absent;
    /// e.g. 0.0254 for inches).
    #[arg(long, env = "CHOREO_BVH_SCALE")]
    pub bvh_scale: Option<f64>,
    /// Keypoint layout of a `.npy` or keypoint `.json` from a video pose
    /// estimator: h36m17 (MotionBERT, VideoPose3D) or mediapipe33.
    #[arg(long)]
    pub keypoints: Option<choreo::motion::keypoints::Layout>,
    /// Frame rate of a file that carries none (keypoint `.npy`, SMPL
    /// parameters from video); overrides a keypoint JSON's own.
    #[arg(long)]
    pub source_fps: Option<f64>,
    /// The file's up axis (y, -y, z, -z, x, -x) where it is not the
    /// format's own (keypoints: -y; WHAM world output: y).
    #[arg(long, allow_hyphen_values = true)]
    pub up: Option<choreo::motion::keypoints::Up>,
    /// Keypoint confidence below which a frame is flagged and bridged.
    #[arg(long)]
    pub min_confidence: Option<f64>,
    /// Keypoint smoothing before the solve: Gaussian σ in seconds (0 = off).
    #[arg(long)]
    pub smooth: Option<f64>,
}

/// `--fps` for commands that only read (inspect, ingest, query): the
/// frame rate of a file that carries none, as `--source-fps` (which
/// `convert` needs, its `--fps` being the output's).
#[derive(clap::Args, Clone)]
pub struct SourceFps {
    /// Frame rate of a keypoint `.npy` or SMPL-from-video file (the same as
    /// --source-fps).
    #[arg(long)]
    pub fps: Option<f64>,
}

impl ReadArgs {
    /// These options with `--fps` folded into `--source-fps`.
    pub fn with_fps(mut self, f: &SourceFps) -> Result<ReadArgs> {
        match (self.source_fps, f.fps) {
            (Some(a), Some(b)) if a != b => {
                bail!("--fps {b} and --source-fps {a} disagree: give one")
            }
            (None, Some(b)) => self.source_fps = Some(b),
            _ => {}
        }
        Ok(self)
    }

    pub fn options(&self) -> ReadOptions {
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
pub enum Cmd {
    /// Print what a motion file holds: format, fps, frames, joints, duration, labels.
    Inspect(super::motion::InspectArgs),
    /// Convert between formats (.bvh or AMASS .npz out), optionally resampled,
    /// cut, mirrored, root-normalised or reduced/retargeted to 13 joints.
    Convert(super::motion::ConvertArgs),
    /// Forward kinematics: joint positions in metres as JSON
    /// `{joints: [names], fps, positions: [frame][joint][xyz]}`.
    Positions(super::motion::PositionsArgs),
    /// Add motion files/folders (any supported format) to a store: windows,
    /// embeddings, PCA refit. Idempotent (same content hash → skipped).
    Ingest(super::archive::IngestArgs),
    /// The stored windows most like a segment of a motion file.
    Query(super::archive::QueryArgs),
    /// Move INPUT's low-frequency features toward TARGET's by gradient
    /// descent (Adam) and write the result (thesis 000 §3.5).
    Interpolate(super::motion::InterpolateArgs),
    /// Zero every DCT coefficient at or above CUTOFF (128-frame units) along time.
    Lowpass(super::motion::LowpassArgs),
    /// Pick keyframes (first and last always kept) and rebuild the
    /// in-betweens; the clip is taken as SMPL-24 at 60 fps.
    Keyframes(super::motion::KeyframesArgs),
    /// Write a model's style exemplars (exemplars.json): a few seconds of
    /// real training motion per label value, which seed generations that
    /// ask for labels.
    Exemplars(super::exemplars::ExemplarsArgs),
    /// Write a frame model's label postures (postures.json): where each
    /// label's training takes hold every joint, for `sampling.posture`.
    Postures(super::postures::PosturesArgs),
    /// Serve REST and gRPC (see README: API).
    Serve(choreo::server::ServeConfig),
    /// Token file lines for `serve --tokens`: new random tokens, hashes.
    Token {
        #[command(subcommand)]
        cmd: super::token::TokenCmd,
    },
    /// Rehearsal footage: keypoint and SMPL test files made from real takes.
    Footage {
        #[command(subcommand)]
        cmd: super::footage::FootageCmd,
    },
    /// Benchmarks whose figures go to bench/RESULTS.md.
    Bench {
        #[command(subcommand)]
        cmd: super::bench::BenchCmd,
    },
    /// Evaluations that reproduce the theses' tables.
    Eval {
        #[command(subcommand)]
        cmd: super::eval::EvalCmd,
    },
    /// Internal checks used by the reference scripts.
    #[command(hide = true)]
    Dev {
        #[command(subcommand)]
        cmd: super::dev::DevCmd,
    },
}

pub fn parse_range(s: &str) -> Result<(usize, usize), String> {
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
