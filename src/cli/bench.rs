//! `choreo bench …`: the benchmarks whose figures go to bench/RESULTS.md.

use super::write_npy_f32;
use anyhow::{bail, Context, Result};
use choreo::index::hnsw::HnswParams;
use choreo::index::{Metric, VectorDtype};
use choreo::motion::io::{self, ReadOptions};
use clap::Subcommand;
use serde_json::json;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCmd {
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
        /// Vector types to store: f32, f16 (flat graph only), or both.
        #[arg(long, value_delimiter = ',', default_value = "f32")]
        dtype: Vec<VectorDtype>,
        /// Also build each graph as the server does (ef_search calibrated
        /// on held-out stored vectors; a second build of every graph).
        #[arg(long)]
        server_build: bool,
        /// Print one JSON object `{"rows": [...]}` (otherwise a table).
        #[arg(long)]
        json: bool,
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
        /// What runs the frame model's local step: kernel (choreo's) or
        /// graph (the runtime's run of the exported graph).
        #[arg(long, default_value = "kernel")]
        local_step: choreo::lm::engine::LocalStep,
        /// Also time a duet: this motion file as the performer (resampled
        /// to the model's frame rate, up to --frames frames), driving
        /// --duet-joints; the answer latency per frame.
        #[arg(long)]
        duet: Option<PathBuf>,
        #[arg(long, value_delimiter = ',', default_value = "Pelvis,Right_Wrist")]
        duet_joints: Vec<String>,
        /// Also time what a request with these labels and no sampling gets
        /// (the model's defaults for the label kinds: candidates, posture
        /// pull, jerk price), streaming from no seed (KIND=VALUE,
        /// repeatable; e.g. `--label style=happy`).
        #[arg(long)]
        label: Vec<String>,
        /// Print one JSON object on one line.
        #[arg(long)]
        json: bool,
    },
    /// Ingest speed of keypoints from video: one long keypoint file (an
    /// hour at 30 fps by default) made from real takes, read + IK alone and
    /// ingested into a fresh store.
    Footage(super::footage::BenchArgs),
    /// Embedding throughput (windows/s) on the real windows of a corpus.
    Embed {
        #[arg(long)]
        data: Vec<PathBuf>,
        /// Write the windows as windows.npy here (for scripts/bench_embed.py).
        #[arg(long)]
        dump: Option<PathBuf>,
    },
}

pub fn run(cmd: BenchCmd) -> Result<()> {
    match cmd {
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
            dtype,
            server_build,
            json,
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
            super::bench_index::run(&super::bench_index::Bench {
                sizes,
                dim,
                queries,
                metric,
                dump,
                params,
                dump_only,
                target_recall,
                backends,
                dtypes: dtype,
                server_build,
                json,
            })
        }
        BenchCmd::Embed { data, dump } => bench_embed(&data, dump.as_deref()),
        BenchCmd::Footage(a) => super::footage::bench(a),
        BenchCmd::Model {
            model,
            repeats,
            frames,
            dump,
            runtime,
            ort_lib,
            local_step,
            duet,
            duet_joints,
            label,
            json,
        } => {
            let engine = choreo::lm::engine::Engine::new(runtime, ort_lib.as_deref())?
                .with_local_step(local_step);
            let duet = duet.as_deref().map(|f| (f, duet_joints.as_slice()));
            let mut labels = choreo::motion::Labels::new();
            for l in &label {
                let (k, v) = l
                    .split_once('=')
                    .ok_or_else(|| anyhow::anyhow!("--label: {l:?} is not KIND=VALUE"))?;
                labels.insert(k.to_string(), v.to_string());
            }
            super::bench_model::run(
                &model,
                &engine,
                repeats,
                frames,
                dump.as_deref(),
                duet,
                &labels,
                json,
            )
        }
        BenchCmd::Keyframes {
            motion,
            frames,
            bpm,
            per_measure,
        } => bench_keyframes(&motion, frames, bpm, per_measure),
    }
}

fn bench_embed(data: &[PathBuf], dump: Option<&std::path::Path>) -> Result<()> {
    use choreo::features::*;
    use std::time::Instant;
    let files = choreo::search::ingest::collect_files(data);
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
        write_npy_f32(
            &d.join("windows.npy"),
            wins[0].len(),
            wins.iter().map(|w| w.as_slice()),
        )?;
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
