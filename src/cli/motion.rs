//! Motion files on the command line: inspect, convert, positions,
//! interpolate, low-pass and keyframes.

use super::args::*;
use anyhow::{bail, Context, Result};
use choreo::features::Embedding;
use choreo::motion::io::{self, bvh, Format, ReadOptions};
use choreo::motion::retarget::{retarget_to_smpl13, JointMap};
use choreo::motion::rotation::*;
use choreo::motion::Motion;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct InspectArgs {
    pub file: PathBuf,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: ReadArgs,
    #[command(flatten)]
    pub fps: SourceFps,
}

#[derive(clap::Args)]
pub struct ConvertArgs {
    pub input: PathBuf,
    pub output: PathBuf,
    /// Resample to this frame rate (SLERP rotations, lerp translation).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Joint set of the output; non-SMPL input is retargeted.
    #[arg(long, value_enum)]
    pub joints: Option<Joints>,
    /// JSON object mapping SMPL joint names to source joint names, for retargeting.
    #[arg(long)]
    pub joint_map: Option<PathBuf>,
    /// Mirror left and right.
    #[arg(long)]
    pub mirror: bool,
    /// Start at the origin facing +z.
    #[arg(long)]
    pub normalize_root: bool,
    /// Keep frames START:END (after resampling), END exclusive.
    #[arg(long, value_parser = parse_range)]
    pub frames: Option<(usize, usize)>,
    /// Unit of BVH output.
    #[arg(long, value_enum, default_value = "cm")]
    pub out_unit: Unit,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[derive(clap::Args)]
pub struct PositionsArgs {
    pub file: PathBuf,
    #[arg(long, value_parser = parse_range)]
    pub frames: Option<(usize, usize)>,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[derive(clap::Args)]
pub struct InterpolateArgs {
    #[arg(long)]
    pub input: PathBuf,
    #[arg(long)]
    pub target: PathBuf,
    /// Band [LO, HI) in coefficients of a 128-frame DCT (0:8 = 0–1.875 Hz).
    #[arg(long, default_value = "0:8", value_parser = parse_range)]
    pub band: (usize, usize),
    #[arg(long, default_value = "dct")]
    pub objective: String,
    #[arg(long, default_value_t = 300)]
    pub steps: usize,
    #[arg(long, default_value_t = 0.02)]
    pub lr: f64,
    #[arg(long)]
    pub out: PathBuf,
    /// Repair short capture glitches first (per joint: jumps > 45° that
    /// come back within 3 frames, replaced by SLERP).
    #[arg(long)]
    pub despike: bool,
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args)]
pub struct LowpassArgs {
    pub input: PathBuf,
    #[arg(long)]
    pub cutoff: usize,
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct KeyframesArgs {
    #[arg(long)]
    pub motion: PathBuf,
    /// A metronome at this tempo stands for the music (onset selection).
    #[arg(long)]
    pub bpm: Option<f64>,
    /// Music file (WAV/Ogg/MP3) for onset selection.
    #[arg(long, conflicts_with = "bpm")]
    pub music: Option<PathBuf>,
    #[arg(long)]
    pub count: usize,
    /// even | onset | percussive | nmfd | dp
    #[arg(long, default_value = "dp")]
    pub select: String,
    /// slerp | bezier | catmull-rom | learned
    #[arg(long, default_value = "slerp")]
    pub inbetween: String,
    /// The learned in-betweener (a folder written by `choreo-train
    /// inbetween`), for `--inbetween learned`.
    #[arg(long, env = "CHOREO_INBETWEENER", default_value = "models/inbetween")]
    pub inbetweener: PathBuf,
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[arg(long)]
    pub json: bool,
}

pub fn inspect_cmd(a: InspectArgs) -> Result<()> {
    let InspectArgs {
        file,
        json,
        read,
        fps,
    } = a;
    inspect(&file, json, &read.with_fps(&fps)?)
}

pub fn convert_cmd(a: ConvertArgs) -> Result<()> {
    let ConvertArgs {
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
    } = a;
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

pub fn positions_cmd(a: PositionsArgs) -> Result<()> {
    let PositionsArgs { file, frames, read } = a;
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

pub fn interpolate_run(a: InterpolateArgs) -> Result<()> {
    let InterpolateArgs {
        input,
        target,
        band,
        objective,
        steps,
        lr,
        out,
        despike,
        json,
    } = a;
    let objective = Embedding::parse(&objective)
        .with_context(|| format!("--objective: '{objective}' is not dct, stft or pca"))?;
    interpolate_cmd(
        &input, &target, band, objective, steps, lr, &out, despike, json,
    )
}

pub fn lowpass_cmd(a: LowpassArgs) -> Result<()> {
    let LowpassArgs { input, cutoff, out } = a;
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

pub fn keyframes_run(a: KeyframesArgs) -> Result<()> {
    let KeyframesArgs {
        motion,
        bpm,
        music,
        count,
        select,
        inbetween,
        inbetweener,
        out,
        json,
    } = a;
    keyframes_cmd(
        motion,
        bpm,
        music,
        count,
        select,
        inbetween,
        &inbetweener,
        out,
        json,
    )
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
        "catmull-rom" => Inbetween::CatmullRom,
        "learned" => Inbetween::Learned(LearnedModel(std::sync::Arc::new(
            choreo::lm::inbetween::Inbetweener::load(inbetweener)
                .with_context(|| format!("--inbetweener {}", inbetweener.display()))?,
        ))),
        other => bail!("--inbetween: '{other}' is not slerp, bezier, catmull-rom or learned"),
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
