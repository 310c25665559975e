//! `choreo-train`: the offline trainer. Reads corpora through the shared
//! readers, tokenizes with the shared vocabulary, trains the motion language
//! model in candle, and exports ONNX + manifest for the server.

use anyhow::{bail, Context, Result};
use choreo::lm::{bits_per_frame, Objective, PosScheme};
use choreo::motion::io::{self, ReadOptions};
use choreo::train::data::{self, Corpus};
use choreo::train::model::Gpt;
use choreo::train::{self as tr, baselines, CheckpointState, RunSettings};
use clap::{Args, Parser, Subcommand, ValueEnum};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

mod alloc;
mod corpus;
mod flat;
mod frame;
mod inbetween;

use choreo::train::flat_run::{class_values, known_kinds, training_json};
use corpus::*;
use flat::*;
use frame::*;
use inbetween::*;

#[derive(Parser)]
#[command(
    name = "choreo-train",
    version,
    about = "Offline trainer for choreo's motion models"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    /// The runtime an exported model (flat or frame) is loaded in for its
    /// parity check against the trainer: tract, or ort (onnxruntime; a
    /// build with the `onnxruntime` feature, and --ort-lib or
    /// ORT_DYLIB_PATH).
    #[arg(long, global = true, default_value = "tract")]
    runtime: choreo::lm::engine::Runtime,
    #[arg(long, global = true)]
    ort_lib: Option<PathBuf>,
}

#[derive(Clone, Copy, ValueEnum)]
enum Positions {
    Absolute,
    FrameSlot,
}
#[derive(Clone, Copy, ValueEnum)]
enum Obj {
    Causal,
    Masked,
}

#[derive(Args, Clone)]
struct DataArgs {
    /// The data root holding aistpp/, bandai/, cmu/ (and amass/ if you have it).
    #[arg(long, env = "CHOREO_DATA", default_value = "../shared/data")]
    data: PathBuf,
    /// Corpora to read: aistpp, aistpp-vrm, bandai, cmu, amass, or any folder of motion files.
    #[arg(long = "corpus", default_values_t = ["aistpp", "aistpp-vrm", "bandai", "cmu"].map(String::from).to_vec())]
    corpora: Vec<String>,
    /// Fraction of each corpus's sequences held out for validation.
    #[arg(long, default_value_t = 0.1)]
    val_fraction: f64,
    /// Skip the left/right mirror augmentation.
    #[arg(long)]
    no_mirror: bool,
    /// Train on this corpus's alike takes played one after another
    /// (`Motion::chain`); held-out takes stay single. Repeatable (bandai).
    #[arg(long = "chain-takes")]
    chain_takes: Vec<String>,
}

#[derive(Args, Clone)]
struct TrainArgs {
    #[command(flatten)]
    data: DataArgs,
    /// Output folder: checkpoint, log, loss curve, export/.
    #[arg(long)]
    out: PathBuf,
    /// Fine-tune from this checkpoint folder (its vocabulary and architecture).
    #[arg(long)]
    init: Option<PathBuf>,
    /// Continue the run saved in --out.
    #[arg(long)]
    resume: bool,
    #[arg(long, default_value_t = 128)]
    d_model: usize,
    #[arg(long, default_value_t = 4)]
    layers: usize,
    #[arg(long, default_value_t = 4)]
    heads: usize,
    /// Frames per context window.
    #[arg(long, default_value_t = 8)]
    frames: usize,
    #[arg(long, value_enum, default_value = "frame-slot")]
    positions: Positions,
    #[arg(long, value_enum, default_value = "causal")]
    objective: Obj,
    /// 13 (the thesis's simplification) or 24 SMPL joints.
    #[arg(long, default_value_t = 13)]
    joints: usize,
    #[arg(long, default_value_t = 20.0)]
    fps: f64,
    /// Label kinds the prefix may carry.
    #[arg(long = "cond", default_values_t = ["genre", "situation", "dancer", "music", "content", "style"].map(String::from).to_vec())]
    cond: Vec<String>,
    /// Label kinds to learn class heads for (none = no heads).
    #[arg(long = "classify")]
    classify: Vec<String>,
    /// Total steps (default 2000). With --resume: a new total, and the
    /// cosine schedule is recomputed over it.
    #[arg(long)]
    steps: Option<usize>,
    #[arg(long, default_value_t = 16)]
    batch: usize,
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    #[arg(long, default_value_t = 0.1)]
    dropout: f32,
    #[arg(long, default_value_t = 200)]
    eval_every: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stop after this many seconds (0 = run all steps).
    #[arg(long, default_value_t = 0.0)]
    max_seconds: f64,
    /// Draw this corpus's training frames W times as often as a length-
    /// weighted draw would (NAME=W, repeatable; e.g. `--corpus-weight
    /// aistpp-vrm=2`), as `choreo-train frame` does. The held-out sets are
    /// unchanged.
    #[arg(long = "corpus-weight", value_name = "NAME=W")]
    corpus_weight: Vec<String>,
    /// Export ONNX + manifest to OUT/export at the end.
    #[arg(long)]
    export: bool,
    /// Instead of training: sweep the learning rate from 1e-6 to 1 over
    /// --steps steps and plot the loss (thesis Fig. 4.9).
    #[arg(long)]
    lr_sweep: bool,
}

#[derive(Subcommand)]
enum Cmd {
    /// Train the frame-level model (global transformer over frames, local
    /// decoder over a frame's slots) and print its held-out table beside
    /// the baselines.
    Frame(Box<FrameArgs>),
    /// Held-out bits/frame of a frame-model checkpoint, per corpus, beside
    /// the unigram, per-slot unigram and previous-frame delta baselines.
    EvalFrame {
        /// A frame-model checkpoint folder, or an exported model folder
        /// such as models/default (its weights read back from the graphs;
        /// the table's class accuracies are then left out: fitted heads
        /// are scored by `fit-heads`).
        #[arg(long)]
        checkpoint: PathBuf,
        #[command(flatten)]
        data: DataArgs,
        /// Also export the checkpoint (both graphs + manifest) to this
        /// folder and check it against the trainer.
        #[arg(long)]
        export: Option<PathBuf>,
    },
    /// Fit an exported frame model's class heads in closed form (shrunk
    /// LDA on the model's mean global state over each training window,
    /// read through the runtime) and score them on the held-out windows
    /// beside the current heads, LDA on token-window statistics and the
    /// majority class. With --out, write the model with the new heads.
    FitHeads {
        /// The exported frame model folder (manifest.json, global.onnx, …).
        #[arg(long)]
        model: PathBuf,
        #[command(flatten)]
        data: DataArgs,
        /// Write a copy of the model with the fitted heads here.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Threads reading windows through the model.
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Also fit on the training sequences' left/right mirrors. Off by
        /// default: a linear head on per-slot statistics cannot be
        /// mirror-invariant, and mirrors cost 2–10 points held out.
        #[arg(long)]
        mirrors: bool,
        /// Label kinds to fit heads for (repeatable). Default: the heads the
        /// model already has. A model exported without heads (a run without
        /// --classify) gets head slots added to its graph first, its other
        /// weights unchanged.
        #[arg(long)]
        classify: Vec<String>,
    },
    /// Read every motion file under DIR and summarise it by corpus.
    Survey {
        #[arg(long, env = "CHOREO_DATA")]
        data: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Train (from scratch, from --init, or --resume) and optionally export.
    Train(Box<TrainArgs>),
    /// Rewrite an exported frame model's local graph as this trainer
    /// exports it (its weights unchanged; the manifest's hash updated) and
    /// check the new graph against the old: with the batch dimension, so
    /// the candidate frames of `sampling.draws` decode side by side, and
    /// one operation per linear layer (fewer operations a step). Models
    /// exported before either still load and run as they are.
    UpgradeFrame {
        #[arg(long)]
        model: PathBuf,
    },
    /// Export a checkpoint as ONNX + manifest.
    Export {
        #[arg(long)]
        checkpoint: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// Compare the exported model, in the --runtime, with the trainer's
    /// forward pass.
    Parity {
        #[arg(long)]
        checkpoint: PathBuf,
    },
    /// Forward tokens/s of the trainer's own forward pass (candle, no
    /// gradient) on one full window, beside `choreo bench model` (tract).
    BenchForward {
        #[arg(long)]
        checkpoint: PathBuf,
        #[arg(long, default_value_t = 20)]
        repeats: usize,
    },
    /// Held-out loss and bits/frame of a checkpoint on the validation split
    /// of the given corpora (the same split training uses).
    Eval {
        #[arg(long)]
        checkpoint: PathBuf,
        #[command(flatten)]
        data: DataArgs,
    },
    /// Classification table shaped like thesis Table 4.8: the model's class
    /// heads vs majority class vs LDA on the same held-out windows.
    EvalClassify {
        #[arg(long)]
        checkpoint: PathBuf,
        #[command(flatten)]
        data: DataArgs,
    },
    /// Train the learned in-betweener (thesis 001 §3.5.3: *Motion*, or
    /// *Genre* with --condition genre), export it to OUT, and compare it
    /// with SLERP and Bézier on the held-out clips.
    Inbetween(Box<InbetweenArgs>),
    /// Held-out comparison of an exported in-betweener with SLERP and
    /// Bézier, per corpus and over all (the same split as training).
    EvalInbetween {
        #[arg(long)]
        model: PathBuf,
        #[command(flatten)]
        data: DataArgs,
        #[arg(long, default_values_t = vec![10, 20, 30], value_delimiter = ',')]
        eval_spacing: Vec<usize>,
        #[arg(long)]
        json: bool,
    },
}

#[derive(Args, Clone)]
struct InbetweenArgs {
    #[command(flatten)]
    data: DataArgs,
    /// Output folder: model.onnx, manifest.json, eval.json.
    #[arg(long)]
    out: PathBuf,
    /// Fine-tune: start from this in-betweener folder (its architecture and
    /// conditioning; the size flags are ignored).
    #[arg(long)]
    init: Option<PathBuf>,
    /// Frames per window (60 fps; even).
    #[arg(long, default_value_t = 64)]
    window: usize,
    #[arg(long, default_value_t = 64)]
    d_model: usize,
    #[arg(long, default_value_t = 2)]
    layers: usize,
    #[arg(long, default_value_t = 4)]
    heads: usize,
    /// Condition on this label kind's values (one-hot), e.g. genre.
    #[arg(long)]
    condition: Option<String>,
    /// The in-betweens the model corrects: slerp (thesis 001 §3.5.3) or
    /// catmull-rom (a spline through the keyframes). Default: the --init
    /// model's, else slerp.
    #[arg(long, value_enum)]
    base: Option<choreo::lm::inbetween::Base>,
    #[arg(long, default_value_t = 1500)]
    steps: usize,
    #[arg(long, default_value_t = 16)]
    batch: usize,
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Smallest and largest keyframe spacing drawn in training (frames).
    #[arg(long, default_values_t = vec![6, 40], num_args = 2)]
    spacing: Vec<usize>,
    /// Draw this share of each batch from one corpus: CORPUS=FRACTION
    /// (e.g. aistpp=0.25).
    #[arg(long)]
    corpus_share: Option<String>,
    /// Add the left/right mirror of every training clip (off by default:
    /// the bundled model was trained without; --no-mirror is ignored here).
    #[arg(long)]
    mirror: bool,
    /// How the loss weighs the pose's numbers: uniform (every number
    /// alike, the bundled model's) or fk (by how far each rotation moves
    /// the FK joint positions the evaluation measures; measured no better,
    /// docs/RESULTS.md "Measured results: keyframes").
    #[arg(long, value_enum, default_value_t = choreo::train::inbetween::LossWeights::Uniform)]
    loss_weights: choreo::train::inbetween::LossWeights,
    /// Held-out spacings evaluated (frames at 60 fps).
    #[arg(long, default_values_t = vec![10, 20, 30], value_delimiter = ',')]
    eval_spacing: Vec<usize>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stop after this many seconds (0 = run all steps).
    #[arg(long, default_value_t = 0.0)]
    max_seconds: f64,
}

fn main() {
    alloc::keep_freed_memory();
    // The training loops log progress through `tracing`: to standard
    // error, plain lines (RUST_LOG overrides the level).
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .without_time()
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    // The trainer checks exported graphs: the runtime runs them itself,
    // not choreo's local kernel (which is checked against them at load).
    let engine = choreo::lm::engine::Engine::new(cli.runtime, cli.ort_lib.as_deref())?
        .with_local_step(choreo::lm::engine::LocalStep::Graph);
    match cli.cmd {
        Cmd::Survey { data, json } => survey(&data, json),
        Cmd::FitHeads {
            model,
            data,
            out,
            threads,
            mirrors,
            classify,
        } => fit_heads(
            &model,
            &data,
            out.as_deref(),
            threads,
            mirrors,
            &classify,
            &engine,
        ),
        Cmd::Train(a) => train(*a, &engine),
        Cmd::Frame(a) => frame(*a, &engine),
        Cmd::EvalFrame {
            checkpoint,
            data,
            export,
        } => {
            let dev = tr::device();
            if checkpoint
                .join(choreo::lm::manifest::MANIFEST_FILE)
                .is_file()
            {
                if export.is_some() {
                    bail!(
                        "--export: {} is already an exported model (it needs a checkpoint folder)",
                        checkpoint.display()
                    );
                }
                let (m, vocab0, net) = tr::frame::net_from_export(&checkpoint, vec![], &dev)?;
                let (vocab, corpus) = load_corpus(&data, Some(&vocab0), &[], false, vocab0.fps)?;
                return print_frame_table(&net, &vocab, &corpus, &m.metrics);
            }
            let (st, net, _) = tr::frame::load(&checkpoint, &dev)?;
            let (vocab, corpus) =
                load_corpus(&data, Some(&st.vocabulary), &[], false, st.vocabulary.fps)?;
            if let Some(dir) = export {
                export_frame(&net, &vocab, &corpus, &st, &dir, &engine)?;
            }
            print_frame_table(&net, &vocab, &corpus, &st.metrics)
        }
        Cmd::UpgradeFrame { model } => {
            match choreo::train::frame_export::upgrade_local(&model)? {
                None => println!(
                    "{}: the local graph is already as this exporter writes it",
                    model.display()
                ),
                Some((one, side)) => {
                    println!(
                        "{}: local graph rewritten as this exporter writes it (batch dimension, one operation per linear layer); largest logit difference from the old graph {one:.2e} (one at a time), {side:.2e} (batched)",
                        model.display()
                    );
                    if one.max(side) > 1e-3 {
                        bail!("the rewritten graph disagrees with the old one");
                    }
                }
            }
            Ok(())
        }
        Cmd::Export { checkpoint, out } => {
            let (_, model, m) = export_checkpoint(&checkpoint, &out)?;
            println!(
                "exported {} ({} parameters) to {}",
                m.onnx,
                model.params.count(),
                out.display()
            );
            Ok(())
        }
        Cmd::Parity { checkpoint } => {
            let dir = tempdir_in(&checkpoint)?;
            let (st, model, _) = export_checkpoint(&checkpoint, &dir)?;
            let r = choreo::train::parity::check(&model, &st.vocabulary, &dir, 7, &engine)?;
            println!("{r}");
            let _ = std::fs::remove_dir_all(&dir);
            Ok(())
        }
        Cmd::EvalClassify { checkpoint, data } => eval_classify(&checkpoint, &data),
        Cmd::Inbetween(a) => inbetween(*a),
        Cmd::EvalInbetween {
            model,
            data,
            eval_spacing,
            json,
        } => eval_inbetween(&model, &data, &eval_spacing, json),
        Cmd::BenchForward {
            checkpoint,
            repeats,
        } => {
            let dev = tr::device();
            let (st, model, _) = tr::load_checkpoint(&checkpoint, &dev)?;
            let cfg = &model.cfg;
            let v = &st.vocabulary;
            let (toks, pos) = choreo::lm::bench_window(cfg, v);
            let n = toks.len();
            let t = candle_core::Tensor::from_vec(toks, (1, n), &dev)?;
            let pa = candle_core::Tensor::from_vec(
                pos.iter().map(|p| p.a as u32).collect::<Vec<_>>(),
                (1, n),
                &dev,
            )?;
            let pb = candle_core::Tensor::from_vec(
                pos.iter().map(|p| p.b as u32).collect::<Vec<_>>(),
                (1, n),
                &dev,
            )?;
            let bias = candle_core::Tensor::from_vec(
                choreo::lm::runtime::attention_bias(cfg.objective, 0, n),
                (1, 1, n, n),
                &dev,
            )?;
            let pbo = (cfg.table_b() > 0).then_some(&pb);
            model.forward(&t, &pa, pbo, &bias, None, false)?;
            let t0 = Instant::now();
            for _ in 0..repeats {
                model.forward(&t, &pa, pbo, &bias, None, false)?;
            }
            let per = t0.elapsed().as_secs_f64() / repeats as f64;
            println!(
                "{}",
                serde_json::json!({"trainer": "candle", "window_tokens": n, "window_forward_ms": per * 1e3, "forward_tokens_per_s": n as f64 / per})
            );
            Ok(())
        }
        Cmd::Eval { checkpoint, data } => {
            let dev = tr::device();
            let (st, model, _) = tr::load_checkpoint(&checkpoint, &dev)?;
            let (vocab, corpus) =
                load_corpus(&data, Some(&st.vocabulary), &[], false, st.vocabulary.fps)?;
            let ev = tr::evaluate(&model, &vocab, &corpus, 16, &dev)?;
            let (uni, slot) = baselines::unigram_losses(
                &corpus.train,
                &corpus.val,
                vocab.size(),
                vocab.frame_len(),
            );
            let fl = vocab.frame_len();
            let delta =
                baselines::delta_loss(&corpus.train, &corpus.val, vocab.size(), vocab.bins, fl);
            println!(
                "{}",
                serde_json::json!({
                    "checkpoint": checkpoint.display().to_string(),
                    "corpora": corpus.info.corpora,
                    "val_sequences": corpus.val.len(),
                    "val_loss": ev.loss,
                    "val_bits_per_frame": ev.bits_per_frame,
                    "unigram_loss": uni,
                    "unigram_bits_per_frame": bits_per_frame(uni, fl),
                    "slot_unigram_loss": slot,
                    "slot_unigram_bits_per_frame": bits_per_frame(slot, fl),
                    "delta_loss": delta,
                    "delta_bits_per_frame": bits_per_frame(delta, fl),
                    "accuracy": ev.accuracy.iter().map(|(k, a, n)| serde_json::json!({"kind": k, "accuracy": a, "windows": n})).collect::<Vec<_>>(),
                })
            );
            Ok(())
        }
    }
}

/// Loads a checkpoint and exports it to `out`.
fn export_checkpoint(
    checkpoint: &Path,
    out: &Path,
) -> Result<(CheckpointState, Gpt, choreo::lm::Manifest)> {
    let (st, model, _) = tr::load_checkpoint(checkpoint, &tr::device())?;
    let m = tr::export::export(
        &model,
        &st.vocabulary,
        st.data.clone(),
        st.metrics.clone(),
        training_json(&st),
        out,
    )?;
    Ok((st, model, m))
}

fn tempdir_in(base: &Path) -> Result<PathBuf> {
    let d = base.join(format!("parity-{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}
