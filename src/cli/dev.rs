//! `choreo dev …`: internal checks the reference scripts call.

use anyhow::{bail, Context, Result};
use choreo::motion::io::{self, ReadOptions};
use choreo::motion::rotation::*;
use clap::Subcommand;
use serde_json::json;
use std::io::Read;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum DevCmd {
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
    /// Read `{"values": [[...] per frame], "keys": [...]}` on stdin; print the
    /// Catmull-Rom in-betweens through those keyframes (`{"values": ...}`).
    CatmullRom,
    /// Read `{"vectors": [[...]...], "sequence": [...]}` on stdin; print the
    /// sequence whitening fitted on them (`mean`, `directions`, `ratios`).
    Whiten {
        #[arg(long, default_value_t = 8)]
        k: usize,
        #[arg(long, default_value_t = 0.01)]
        shrink: f64,
    },
}

pub fn run(cmd: DevCmd) -> Result<()> {
    match cmd {
        DevCmd::Rotations => dev_rotations(),
        DevCmd::CatmullRom => dev_catmull_rom(),
        DevCmd::Whiten { k, shrink } => {
            let mut s = String::new();
            std::io::stdin().read_to_string(&mut s)?;
            let v: serde_json::Value = serde_json::from_str(&s)?;
            let vectors: Vec<Vec<f32>> =
                serde_json::from_value(v["vectors"].clone()).context("vectors")?;
            let sequence: Vec<usize> =
                serde_json::from_value(v["sequence"].clone()).context("sequence")?;
            let refs: Vec<&[f32]> = vectors.iter().map(|x| x.as_slice()).collect();
            let w = choreo::features::whiten::Whitening::fit(&refs, &sequence, k, shrink)
                .context("not enough sequences, or vectors of unequal length")?;
            println!(
                "{}",
                json!({"mean": w.mean, "directions": w.directions, "ratios": w.ratios})
            );
            Ok(())
        }
        DevCmd::Audio { music, out } => {
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
        DevCmd::Features {
            motion,
            start,
            pca_on,
        } => dev_features(&motion, start, &pca_on),
    }
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

fn dev_catmull_rom() -> Result<()> {
    let mut s = String::new();
    std::io::stdin().read_to_string(&mut s)?;
    let v: serde_json::Value = serde_json::from_str(&s)?;
    let values: Vec<Vec<f64>> = serde_json::from_value(v["values"].clone()).context("values")?;
    let keys: Vec<usize> = serde_json::from_value(v["keys"].clone()).context("keys")?;
    let channels = values.first().map_or(0, |r| r.len());
    if channels == 0 || values.iter().any(|r| r.len() != channels) {
        bail!("values: rows of one positive length");
    }
    if keys.len() < 2
        || keys[0] != 0
        || keys[keys.len() - 1] != values.len() - 1
        || keys.windows(2).any(|w| w[1] <= w[0])
    {
        bail!("keys: strictly increasing from 0 to the last frame");
    }
    let x = choreo::tokenize::Series {
        channels,
        data: values.concat(),
    };
    let out = choreo::keyframes::inbetween::catmull_rom_series(&x, &keys);
    let rows: Vec<&[f64]> = out.data.chunks(channels).collect();
    println!("{}", json!({ "values": rows }));
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
