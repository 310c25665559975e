//! `choreo-train`: the offline trainer. Reads corpora through the shared
//! readers, tokenizes with the shared vocabulary, trains the motion language
//! model in candle, and exports ONNX + manifest for the server.

use anyhow::{bail, Context, Result};
use choreo::lm::{bits_per_frame, ModelConfig, Objective, PosScheme};
use choreo::motion::io::{self, ReadOptions};
use choreo::plot::{render_png, Chart, Line, PALETTE};
use choreo::train::data::{self, Corpus};
use choreo::train::model::{AdamW, Gpt};
use choreo::train::{self as tr, baselines, CheckpointState, LogPoint, RunSettings};
use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

// Training allocates and frees large attention tensors every step; glibc
// hands them back to the kernel each time and page faults ate more time than
// the arithmetic (measured: 5.9 s system vs 7.6 s user over 20 steps).
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

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
    #[arg(long, default_value_t = 2000)]
    steps: usize,
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
    /// Export ONNX + manifest to OUT/export at the end.
    #[arg(long)]
    export: bool,
    /// Instead of training: sweep the learning rate from 1e-6 to 1 over
    /// --steps steps and plot the loss (thesis Fig. 4.9).
    #[arg(long)]
    lr_sweep: bool,
}

#[derive(Args, Clone)]
struct FrameArgs {
    #[command(flatten)]
    data: DataArgs,
    /// Output folder: checkpoint (resumable) and the final metrics.
    #[arg(long)]
    out: PathBuf,
    /// Continue the run saved in --out.
    #[arg(long)]
    resume: bool,
    /// Start a new run from the weights of this frame-model checkpoint
    /// folder (its vocabulary too); parameters it lacks keep their fresh
    /// initialisation (e.g. `g_cond_all` when adding --cond-every).
    #[arg(long, conflicts_with = "resume")]
    init_from: Option<PathBuf>,
    /// Export the configured network with its random initial weights to
    /// --out/export and stop (no training, no evaluation): for timing
    /// bigger models (`choreo bench model`) before spending CPU on them.
    #[arg(long, conflicts_with_all = ["resume", "init_from"])]
    untrained: bool,
    /// Feed the conditioning into every frame's global input, not only
    /// position 0, and train with whole-conditioning dropout (guidance).
    #[arg(long)]
    cond_every: bool,
    /// Largest per-frame change (bins) the change head names.
    #[arg(long, default_value_t = 24)]
    radius: usize,
    #[arg(long, default_value_t = 16)]
    d_emb: usize,
    #[arg(long, default_value_t = 192)]
    d_global: usize,
    #[arg(long, default_value_t = 4)]
    global_layers: usize,
    #[arg(long, default_value_t = 4)]
    global_heads: usize,
    #[arg(long, default_value_t = 64)]
    d_local: usize,
    #[arg(long, default_value_t = 2)]
    local_layers: usize,
    #[arg(long, default_value_t = 4)]
    local_heads: usize,
    /// Frames of global context (200 = 10 s at 20 fps).
    #[arg(long, default_value_t = 64)]
    frames: usize,
    #[arg(long, default_value_t = 20.0)]
    fps: f64,
    /// Label kinds the conditioning may carry.
    #[arg(long = "cond", default_values_t = ["genre", "situation", "dancer", "content", "style"].map(String::from).to_vec())]
    cond: Vec<String>,
    /// Label kinds to learn class heads for (none = no heads).
    #[arg(long = "classify")]
    classify: Vec<String>,
    /// Total steps (default 4000). With --resume: a new total, and the
    /// cosine schedule is recomputed over it.
    #[arg(long)]
    steps: Option<usize>,
    #[arg(long, default_value_t = 8)]
    batch: usize,
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    #[arg(long, default_value_t = 100)]
    eval_every: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stop after this many seconds of training, resumed runs included
    /// (0 = run all steps).
    #[arg(long, default_value_t = 0.0)]
    max_seconds: f64,
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
        #[arg(long)]
        checkpoint: PathBuf,
        #[command(flatten)]
        data: DataArgs,
        /// Also export the checkpoint (both graphs + manifest) to this
        /// folder and check it against the trainer.
        #[arg(long)]
        export: Option<PathBuf>,
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
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    let engine = choreo::lm::engine::Engine::new(cli.runtime, cli.ort_lib.as_deref())?;
    match cli.cmd {
        Cmd::Survey { data, json } => survey(&data, json),
        Cmd::Train(a) => train(*a, &engine),
        Cmd::Frame(a) => frame(*a, &engine),
        Cmd::EvalFrame {
            checkpoint,
            data,
            export,
        } => {
            let dev = tr::device();
            let (st, net, _) = tr::frame::load(&checkpoint, &dev)?;
            let (vocab, corpus) =
                load_corpus(&data, Some(&st.vocabulary), &[], false, st.vocabulary.fps)?;
            if let Some(dir) = export {
                export_frame(&net, &vocab, &corpus, &st, &dir, &engine)?;
            }
            print_frame_table(&net, &vocab, &corpus, &st.metrics)
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

fn frame(a: FrameArgs, engine: &choreo::lm::engine::Engine) -> Result<()> {
    let mut kinds = a.cond.clone();
    for k in &a.classify {
        if !kinds.contains(k) {
            kinds.push(k.clone());
        }
    }
    let known = if a.resume || a.init_from.is_some() {
        let from = a.init_from.as_ref().unwrap_or(&a.out);
        let (st, _, _): (tr::frame::FrameState, _, _) = tr::load_parts(from, &tr::device())?;
        Some(st.vocabulary)
    } else {
        None
    };
    let (vocab, corpus) = load_corpus(&a.data, known.as_ref(), &kinds, false, a.fps)?;
    eprintln!(
        "data: {} files from {:?}; {} train / {} validation sequences; {} training tokens (mirrors included)",
        corpus.info.files,
        corpus.info.corpora,
        corpus.info.train_sequences,
        corpus.info.val_sequences,
        corpus.info.train_tokens
    );
    let run = tr::frame::FrameRun {
        out: a.out.clone(),
        resume: a.resume,
        init_from: a.init_from.clone(),
        config: choreo::lm::frame::FrameConfig {
            bins: vocab.bins,
            slots: vocab.frame_len() - 1,
            radius: a.radius,
            d_emb: a.d_emb,
            d_global: a.d_global,
            global_layers: a.global_layers,
            global_heads: a.global_heads,
            d_local: a.d_local,
            local_layers: a.local_layers,
            local_heads: a.local_heads,
            max_frames: a.frames,
            vocab_size: vocab.size(),
            cond_kinds: known_kinds(&vocab, &a.cond),
            classes: class_values(&vocab, &a.classify)?,
            ln_eps: 1e-5,
            cond_every: a.cond_every,
        },
        resume_steps: a.steps,
        settings: RunSettings {
            steps: a.steps.unwrap_or(4000),
            batch: a.batch,
            lr: a.lr,
            min_lr_ratio: 0.1,
            warmup: (a.steps.unwrap_or(4000) / 50).max(1),
            weight_decay: 0.05,
            dropout: 0.0,
            eval_every: a.eval_every.max(1),
            seed: a.seed,
            keep_label: 0.8,
            classify_fraction: if a.classify.is_empty() { 0.0 } else { 0.25 },
            class_weight: 1.0,
            mask_rate: 0.0,
            max_seconds: a.max_seconds,
        },
    };
    if a.untrained {
        let cfg = run.config.clone();
        cfg.validate("--frame flags")
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let net = tr::frame::FrameNet::new(cfg.clone(), &tr::device())?;
        let mut st = tr::frame::FrameState::fresh(cfg, &vocab, &run.settings, &corpus);
        st.metrics
            .insert("parameters".to_string(), net.params.count() as f64);
        export_frame(&net, &vocab, &corpus, &st, &a.out.join("export"), engine)?;
        eprintln!(
            "untrained model, {} parameters, exported to {}",
            net.params.count(),
            a.out.join("export").display()
        );
        return Ok(());
    }
    let st = tr::frame::run(&run, &vocab, &corpus)?;
    let net = tr::frame::load(&a.out, &tr::device())?.1;
    export_frame(&net, &vocab, &corpus, &st, &a.out.join("export"), engine)?;
    print_frame_table(&net, &vocab, &corpus, &st.metrics)
}

/// Exports a frame model and checks the export against the trainer on the
/// first held-out sequence.
fn export_frame(
    net: &tr::frame::FrameNet,
    vocab: &choreo::tokenize::vocab::Vocabulary,
    corpus: &Corpus,
    st: &tr::frame::FrameState,
    dir: &Path,
    engine: &choreo::lm::engine::Engine,
) -> Result<()> {
    let training = serde_json::json!({
        "steps": st.step,
        "settings": st.settings,
        "train_seconds": st.train_seconds,
        "history": st.history,
    });
    let m = tr::frame_export::export(
        net,
        vocab,
        st.data.clone(),
        st.metrics.clone(),
        training,
        dir,
    )?;
    let seq = corpus
        .val
        .first()
        .or(corpus.train.first())
        .context("no sequence for the parity check")?;
    let values = tr::frame::value_frames(&seq.tokens, vocab.frame_len());
    let labels = vocab.known_labels(&seq.labels);
    let labels = labels
        .into_iter()
        .filter(|(k, _)| net.cfg.cond_kinds.contains(k))
        .collect();
    let (worst, scale) = tr::frame_export::parity(net, vocab, dir, &values, &labels, engine)?;
    eprintln!(
        "exported {} + {} to {}; parity on {}: max |{} − trainer| = {worst:.2e} (logits up to {scale:.1})",
        m.global_onnx,
        m.local_onnx,
        dir.display(),
        seq.name,
        engine.runtime().name()
    );
    Ok(())
}

/// Prints the frame model's per-corpus table (one JSON line per row on
/// standard error as it comes, then all of it with the run's metrics).
fn print_frame_table(
    net: &tr::frame::FrameNet,
    vocab: &choreo::tokenize::vocab::Vocabulary,
    corpus: &Corpus,
    metrics: &BTreeMap<String, f64>,
) -> Result<()> {
    let rows = tr::frame::table(net, vocab, corpus)?;
    for r in &rows {
        eprintln!("{r}");
    }
    println!(
        "{}",
        serde_json::to_string_pretty(&serde_json::json!({"rows": rows, "metrics": metrics}))?
    );
    Ok(())
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

fn training_json(st: &CheckpointState) -> serde_json::Value {
    serde_json::json!({
        "regime": st.regime,
        "parent": st.parent,
        "steps": st.step,
        "settings": st.settings,
        "final": st.history.last(),
    })
}

fn survey(data: &Path, json: bool) -> Result<()> {
    let files = choreo::data::files_with_ext(data, &["pkl", "npz", "bvh"]);
    let mut by: BTreeMap<String, (usize, usize, f64)> = BTreeMap::new();
    let mut errors = Vec::new();
    for f in &files {
        match io::read_path(f, &ReadOptions::default()) {
            Ok(l) => {
                let m = l.motion;
                let corpus = m
                    .labels
                    .get("corpus")
                    .cloned()
                    .unwrap_or_else(|| l.format.name().to_string());
                let e = by.entry(corpus).or_default();
                e.0 += 1;
                e.1 += m.frames();
                e.2 += m.duration_s();
            }
            Err(e) => errors.push(
                serde_json::json!({"file": f.display().to_string(), "reason": e.to_string()}),
            ),
        }
    }
    if json {
        let corpora: Vec<_> = by
            .iter()
            .map(|(k, v)| serde_json::json!({"corpus": k, "files": v.0, "frames": v.1, "seconds": v.2}))
            .collect();
        println!(
            "{}",
            serde_json::json!({"corpora": corpora, "errors": errors})
        );
    } else {
        println!(
            "{:<12} {:>6} {:>9} {:>9}",
            "corpus", "files", "frames", "seconds"
        );
        for (k, v) in &by {
            println!("{:<12} {:>6} {:>9} {:>9.1}", k, v.0, v.1, v.2);
        }
        for e in &errors {
            println!("unreadable: {} — {}", e["file"], e["reason"]);
        }
    }
    Ok(())
}

fn load_corpus(
    a: &DataArgs,
    vocab: Option<&choreo::tokenize::vocab::Vocabulary>,
    kinds: &[String],
    smpl24: bool,
    fps: f64,
) -> Result<(choreo::tokenize::vocab::Vocabulary, Corpus)> {
    let dirs = data::corpus_dirs(&a.data, &a.corpora)?;
    let (motions, info) = data::read_motions(&dirs)?;
    let vocab = match vocab {
        Some(v) => v.clone(),
        None => {
            let mut v = data::vocabulary_for(&motions, kinds, smpl24);
            v.fps = fps;
            v
        }
    };
    let corpus = data::build(motions, &vocab, a.val_fraction, !a.no_mirror, info)?;
    Ok((vocab, corpus))
}

fn train(a: TrainArgs, engine: &choreo::lm::engine::Engine) -> Result<()> {
    let dev = tr::device();
    let t0 = Instant::now();
    let mut kinds = a.cond.clone();
    for k in &a.classify {
        if !kinds.contains(k) {
            kinds.push(k.clone());
        }
    }
    if a.joints != 13 && a.joints != 24 {
        bail!("--joints: {} (13 or 24)", a.joints);
    }
    // The starting point: resume, fine-tune, or scratch.
    let resume_state = if a.resume {
        Some(tr::load_checkpoint(&a.out, &dev)?)
    } else {
        None
    };
    let init_state = match (&a.init, &resume_state) {
        (Some(p), None) => Some(tr::load_checkpoint(p, &dev)?),
        _ => None,
    };
    let known_vocab = resume_state
        .as_ref()
        .or(init_state.as_ref())
        .map(|s| s.0.vocabulary.clone());
    let (vocab, corpus) =
        load_corpus(&a.data, known_vocab.as_ref(), &kinds, a.joints == 24, a.fps)?;
    let fl = vocab.frame_len();
    eprintln!(
        "data: {} files from {:?}; {} train / {} validation sequences; {} training tokens (mirrors included); read in {:.1} s",
        corpus.info.files,
        corpus.info.corpora,
        corpus.info.train_sequences,
        corpus.info.val_sequences,
        corpus.info.train_tokens,
        t0.elapsed().as_secs_f64()
    );
    let settings = RunSettings {
        steps: a.steps,
        batch: a.batch,
        lr: a.lr,
        min_lr_ratio: 0.1,
        warmup: (a.steps / 20).max(1),
        weight_decay: 0.1,
        dropout: a.dropout,
        eval_every: a.eval_every.max(1),
        seed: a.seed,
        keep_label: 0.8,
        classify_fraction: if a.classify.is_empty() { 0.0 } else { 0.5 },
        class_weight: 1.0,
        mask_rate: 0.15,
        max_seconds: a.max_seconds,
    };
    let (mut state, model, mut opt) = match (resume_state, init_state) {
        (Some((st, m, o)), _) => (st, m, o),
        (None, Some((st, mut m, _))) => {
            // Fine-tune: same architecture and vocabulary, fresh optimiser;
            // class heads may be added.
            let mut cfg = st.config.clone();
            cfg.classes = class_values(&vocab, &a.classify)?;
            if cfg.classes != st.config.classes {
                let mut fresh = Gpt::new(cfg.clone(), a.dropout, &dev)?;
                for (k, v) in m.params.iter() {
                    if let Some(dst) = fresh.params.get(k) {
                        if dst.dims() == v.dims() {
                            dst.set(v.as_tensor())?;
                        }
                    }
                }
                fresh.dropout = a.dropout;
                m = fresh;
            }
            m.dropout = a.dropout;
            let regime = if a.classify.is_empty() {
                "fine-tune"
            } else {
                "fine-tune+classify"
            };
            let parent = a.init.as_ref().map(|p| p.display().to_string());
            let s = new_state(cfg, &vocab, &settings, regime, parent, &corpus);
            (s, m, AdamW::new(a.lr, settings.weight_decay))
        }
        (None, None) => {
            let cfg = ModelConfig {
                vocab_size: vocab.size(),
                d_model: a.d_model,
                n_layers: a.layers,
                n_heads: a.heads,
                d_ff: 4 * a.d_model,
                max_frames: a.frames,
                frame_len: fl,
                cond_kinds: known_kinds(&vocab, &a.cond),
                classes: class_values(&vocab, &a.classify)?,
                positions: match a.positions {
                    Positions::Absolute => PosScheme::Absolute,
                    Positions::FrameSlot => PosScheme::FrameSlot,
                },
                objective: match a.objective {
                    Obj::Causal => Objective::Causal,
                    Obj::Masked => Objective::Masked,
                },
                ln_eps: 1e-5,
            };
            cfg.validate("--d-model/--heads")
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let m = Gpt::new(cfg.clone(), a.dropout, &dev)?;
            let s = new_state(cfg, &vocab, &settings, "scratch", None, &corpus);
            (s, m, AdamW::new(a.lr, settings.weight_decay))
        }
    };
    let s = state.settings.clone();
    eprintln!(
        "model: {} parameters, d_model {}, {} layers, {} heads, window {} frames ({} tokens), {:?} positions, {:?}; regime {}",
        model.params.count(),
        model.cfg.d_model,
        model.cfg.n_layers,
        model.cfg.n_heads,
        model.cfg.max_frames,
        model.cfg.block(),
        model.cfg.positions,
        model.cfg.objective,
        state.regime
    );
    let cum = tr::cumulative(&corpus, fl);
    let mut rng = StdRng::seed_from_u64(s.seed.wrapping_add(state.step as u64));
    std::fs::create_dir_all(&a.out)?;

    if a.lr_sweep {
        return lr_sweep(&a, &model, &vocab, &corpus, &cum, &s, &mut rng);
    }

    let pb = ProgressBar::new(s.steps as u64);
    pb.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} steps · {msg} · {elapsed_precise} < {eta_precise}",
        )
        .expect("template"),
    );
    pb.set_position(state.step as u64);
    let t_train = Instant::now();
    let (mut tok_acc, mut loss_acc, mut n_acc) = (0usize, 0f64, 0usize);
    let mut t_win = Instant::now();
    let mut tokens_total = 0usize;
    while state.step < s.steps {
        if s.max_seconds > 0.0 && t_train.elapsed().as_secs_f64() > s.max_seconds {
            say(&pb, format!("time limit reached at step {}", state.step));
            break;
        }
        opt.lr = tr::lr_at(&s, state.step);
        let (loss, toks) =
            tr::train_step(&model, &mut opt, &vocab, &corpus, &cum, &s, &mut rng, &dev)?;
        state.step += 1;
        tok_acc += toks;
        tokens_total += toks;
        loss_acc += loss;
        n_acc += 1;
        let tps = tok_acc as f64 / t_win.elapsed().as_secs_f64().max(1e-9);
        pb.set_message(format!("loss {loss:.3} · {tps:.0} tok/s"));
        pb.set_position(state.step as u64);
        if state.step % s.eval_every == 0 || state.step == s.steps {
            let ev = tr::evaluate(&model, &vocab, &corpus, s.batch, &dev)?;
            let point = LogPoint {
                step: state.step,
                lr: opt.lr,
                train_loss: loss_acc / n_acc as f64,
                val_loss: Some(ev.loss),
                val_bits_per_frame: Some(ev.bits_per_frame),
                tokens_per_s: tps,
            };
            let acc: Vec<String> = ev
                .accuracy
                .iter()
                .map(|(k, a, n)| format!("{k} {:.1}% of {n}", 100.0 * a))
                .collect();
            say(
                &pb,
                format!(
                    "step {:>6}  train {:.4}  val {:.4} ({:.1} bits/frame)  {:.0} tok/s  {}",
                    state.step,
                    point.train_loss,
                    ev.loss,
                    ev.bits_per_frame,
                    tps,
                    acc.join("  ")
                ),
            );
            state.history.push(point);
            state.adam_step = opt.step;
            tr::save_checkpoint(&a.out, &model, &opt, &state)?;
            plot_history(&state.history, &a.out.join("loss.png"))?;
            (tok_acc, loss_acc, n_acc) = (0, 0.0, 0);
            t_win = Instant::now();
        }
    }
    pb.finish_and_clear();
    let secs = t_train.elapsed().as_secs_f64();
    // Final held-out figures and the unigram floor on the same tokens.
    let ev = tr::evaluate(&model, &vocab, &corpus, s.batch, &dev)?;
    let (uni, uni_slot) = baselines::unigram_losses(&corpus.train, &corpus.val, vocab.size(), fl);
    let m = &mut state.metrics;
    m.insert("val_loss".into(), ev.loss);
    m.insert("val_bits_per_frame".into(), ev.bits_per_frame);
    m.insert("unigram_loss".into(), uni);
    m.insert("unigram_bits_per_frame".into(), bits_per_frame(uni, fl));
    m.insert("slot_unigram_loss".into(), uni_slot);
    m.insert(
        "slot_unigram_bits_per_frame".into(),
        bits_per_frame(uni_slot, fl),
    );
    let delta = baselines::delta_loss(&corpus.train, &corpus.val, vocab.size(), vocab.bins, fl);
    m.insert("delta_loss".into(), delta);
    m.insert("delta_bits_per_frame".into(), bits_per_frame(delta, fl));
    m.insert(
        "train_tokens_per_s".into(),
        tokens_total as f64 / secs.max(1e-9),
    );
    m.insert("train_seconds".into(), secs);
    m.insert("parameters".into(), model.params.count() as f64);
    for (k, acc, n) in &ev.accuracy {
        m.insert(format!("val_accuracy_{k}"), *acc);
        m.insert(format!("val_windows_{k}"), *n as f64);
    }
    state.adam_step = opt.step;
    tr::save_checkpoint(&a.out, &model, &opt, &state)?;
    plot_history(&state.history, &a.out.join("loss.png"))?;
    println!(
        "{}",
        serde_json::to_string_pretty(&serde_json::json!({
            "out": a.out.display().to_string(),
            "regime": state.regime,
            "steps": state.step,
            "metrics": state.metrics,
        }))?
    );
    if a.export {
        let dir = a.out.join("export");
        let mf = tr::export::export(
            &model,
            &vocab,
            state.data.clone(),
            state.metrics.clone(),
            training_json(&state),
            &dir,
        )?;
        let r = tr::parity::check(&model, &vocab, &dir, s.seed + 1, engine)?;
        eprintln!("exported {} to {}; {r}", mf.onnx, dir.display());
    }
    Ok(())
}

/// A log line above the bar, or on standard error when there is no bar
/// (not a terminal).
fn say(pb: &ProgressBar, line: String) {
    if pb.is_hidden() {
        eprintln!("{line}");
    } else {
        pb.println(line);
    }
}

/// The state of a run that has not taken a step yet.
fn new_state(
    config: ModelConfig,
    vocab: &choreo::tokenize::vocab::Vocabulary,
    settings: &RunSettings,
    regime: &str,
    parent: Option<String>,
    corpus: &Corpus,
) -> CheckpointState {
    CheckpointState {
        config,
        vocabulary: vocab.clone(),
        settings: settings.clone(),
        step: 0,
        adam_step: 0,
        history: Vec::new(),
        regime: regime.into(),
        parent,
        data: corpus.info.clone(),
        metrics: BTreeMap::new(),
    }
}

/// The label kinds asked for that the vocabulary has values of.
fn known_kinds(vocab: &choreo::tokenize::vocab::Vocabulary, kinds: &[String]) -> Vec<String> {
    kinds
        .iter()
        .filter(|k| vocab.labels.contains_key(*k))
        .cloned()
        .collect()
}

fn class_values(
    vocab: &choreo::tokenize::vocab::Vocabulary,
    kinds: &[String],
) -> Result<Vec<(String, Vec<String>)>> {
    kinds
        .iter()
        .map(|k| {
            let v = vocab.labels.get(k).with_context(|| {
                format!("--classify {k}: no motion in the data carries that label")
            })?;
            if v.len() < 2 {
                bail!("--classify {k}: only one value ({v:?}) in the data");
            }
            Ok((k.clone(), v.iter().cloned().collect()))
        })
        .collect()
}

fn plot_history(h: &[LogPoint], path: &Path) -> Result<()> {
    let train: Vec<(f64, f64)> = h.iter().map(|p| (p.step as f64, p.train_loss)).collect();
    let val: Vec<(f64, f64)> = h
        .iter()
        .filter_map(|p| p.val_loss.map(|v| (p.step as f64, v)))
        .collect();
    let chart = Chart {
        title: "motion language model: loss per token".into(),
        x_label: "step".into(),
        y_label: "loss (nats/token)".into(),
        log_x: false,
        log_y: false,
        lines: vec![
            Line {
                name: "train".into(),
                points: train,
                color: PALETTE[0],
            },
            Line {
                name: "validation".into(),
                points: val,
                color: PALETTE[1],
            },
        ],
    };
    std::fs::write(path, render_png(&chart, 800, 500))?;
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn lr_sweep(
    a: &TrainArgs,
    model: &Gpt,
    vocab: &choreo::tokenize::vocab::Vocabulary,
    corpus: &Corpus,
    cum: &[usize],
    s: &RunSettings,
    rng: &mut StdRng,
) -> Result<()> {
    let dev = tr::device();
    let mut opt = AdamW::new(1e-6, s.weight_decay);
    let (lo, hi) = (1e-6f64, 1.0f64);
    let mut pts = Vec::new();
    let mut smooth = None;
    let mut best = f64::INFINITY;
    for i in 0..s.steps {
        let lr = lo * (hi / lo).powf(i as f64 / (s.steps - 1).max(1) as f64);
        opt.lr = lr;
        let (loss, _) = match tr::train_step(model, &mut opt, vocab, corpus, cum, s, rng, &dev) {
            Ok(x) => x,
            Err(_) => break,
        };
        let sm = match smooth {
            None => loss,
            Some(p) => 0.9 * p + 0.1 * loss,
        };
        smooth = Some(sm);
        best = best.min(sm);
        pts.push((lr, sm));
        eprintln!("lr {lr:.2e}  loss {loss:.4}  smoothed {sm:.4}");
        if sm > 4.0 * best && i > 10 {
            break;
        }
    }
    // The thesis's rule (Fig. 4.9): a tenth of where the loss turns up.
    let turn = pts
        .iter()
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .map(|p| p.0)
        .unwrap_or(1e-3);
    let chart = Chart {
        title: "learning-rate sweep".into(),
        x_label: "learning rate".into(),
        y_label: "smoothed loss".into(),
        log_x: true,
        log_y: false,
        lines: vec![Line {
            name: "loss".into(),
            points: pts.clone(),
            color: PALETTE[0],
        }],
    };
    std::fs::write(a.out.join("lr_sweep.png"), render_png(&chart, 800, 500))?;
    std::fs::write(
        a.out.join("lr_sweep.json"),
        serde_json::to_string_pretty(&pts)?,
    )?;
    println!(
        "loss turns up near lr {turn:.2e}; suggested lr {:.2e} (a tenth of it)",
        turn / 10.0
    );
    Ok(())
}

fn eval_classify(ckpt: &Path, a: &DataArgs) -> Result<()> {
    let dev = tr::device();
    let (st, model, _) = tr::load_checkpoint(ckpt, &dev)?;
    if st.config.classes.is_empty() {
        bail!(
            "{}: the model has no class heads (train with --classify KIND)",
            ckpt.display()
        );
    }
    let kinds: Vec<String> = st.config.classes.iter().map(|c| c.0.clone()).collect();
    let (vocab, corpus) = load_corpus(a, Some(&st.vocabulary), &kinds, false, st.vocabulary.fps)?;
    let fl = vocab.frame_len();
    let w = st.config.max_frames;
    // Every held-out window, the same ones the baselines see.
    let ev = tr::evaluate_on(&model, &vocab, &corpus, 16, &dev, usize::MAX)?;
    let train_w = data::eval_windows(&corpus.train, fl, w);
    let val_w = data::eval_windows(&corpus.val, fl, w);
    println!("Classification accuracy (%) on held-out windows of {w} frames ({} validation sequences of {:?})", corpus.val.len(), corpus.info.corpora);
    println!(
        "{:<22} {}",
        "method",
        kinds.iter().map(|k| format!("{k:>10}")).collect::<String>()
    );
    let mut rows: Vec<(String, Vec<f64>)> = vec![
        ("majority class".into(), vec![]),
        ("LDA".into(), vec![]),
        ("our model".into(), vec![]),
    ];
    let mut ns = Vec::new();
    for (k, values) in &st.config.classes {
        let (maj, lda, n) =
            baselines::classification_baselines(&train_w, &val_w, k, values, fl, vocab.bins);
        rows[0].1.push(100.0 * maj);
        rows[1].1.push(100.0 * lda);
        let acc = ev
            .accuracy
            .iter()
            .find(|x| &x.0 == k)
            .map(|x| x.1)
            .unwrap_or(0.0);
        rows[2].1.push(100.0 * acc);
        ns.push(n);
    }
    for (name, v) in rows {
        println!(
            "{:<22} {}",
            name,
            v.iter().map(|x| format!("{x:>10.1}")).collect::<String>()
        );
    }
    println!(
        "{:<22} {}",
        "windows",
        ns.iter().map(|x| format!("{x:>10}")).collect::<String>()
    );
    Ok(())
}

fn inbetween(a: InbetweenArgs) -> Result<()> {
    use choreo::lm::inbetween::{InbetweenConfig, Inbetweener};
    use choreo::train::inbetween as ib;
    use rand::SeedableRng;
    let cfg = InbetweenConfig {
        window: a.window,
        d_model: a.d_model,
        n_layers: a.layers,
        n_heads: a.heads,
        d_ff: 4 * a.d_model,
        ln_eps: 1e-5,
        condition: None,
    };
    let dirs = choreo::train::data::corpus_dirs(&a.data.data, &a.data.corpora)?;
    let (motions, info) = choreo::train::data::read_motions(&dirs)?;
    let condition = match &a.condition {
        None => None,
        Some(kind) => {
            let values: std::collections::BTreeSet<String> = motions
                .iter()
                .filter_map(|(_, m)| m.labels.get(kind).cloned())
                .collect();
            if values.is_empty() {
                anyhow::bail!("--condition {kind}: no motion carries that label");
            }
            Some((kind.clone(), values.into_iter().collect::<Vec<_>>()))
        }
    };
    let init = a.init.as_deref().map(Inbetweener::load).transpose()?;
    let cfg = match &init {
        Some(m) => m.manifest.config.clone(),
        None => InbetweenConfig { condition, ..cfg },
    };
    cfg.validate("--window/--d-model/--heads")?;
    let (train, val) = ib::prepare(motions, a.data.val_fraction, cfg.window + 1, a.mirror)?;
    let corpus_share = match &a.corpus_share {
        None => None,
        Some(v) => {
            let (c, f) = v
                .split_once('=')
                .with_context(|| format!("--corpus-share: '{v}' is not CORPUS=FRACTION"))?;
            let f: f64 = f
                .parse()
                .ok()
                .filter(|f| (0.0..=1.0).contains(f))
                .with_context(|| format!("--corpus-share: '{f}' is not a fraction in 0..=1"))?;
            Some((c.to_string(), f))
        }
    };
    eprintln!(
        "{} training clips, {} held out ({} corpora)",
        train.len(),
        val.len(),
        info.corpora.len()
    );
    let dev = choreo::train::device();
    let net = ib::InbetweenNet::new(cfg.clone(), &dev)?;
    if let Some(m) = &init {
        net.load_from_export(m, &dev)?;
        eprintln!("fine-tuning from {}", m.onnx_path.display());
    }
    eprintln!("{} parameters", net.params.count());
    let settings = ib::Settings {
        steps: a.steps,
        batch: a.batch,
        lr: a.lr,
        warmup: (a.steps / 20).max(1),
        weight_decay: 0.01,
        spacing: (a.spacing[0].max(2), a.spacing[1].max(a.spacing[0].max(2))),
        seed: a.seed,
        max_seconds: (a.max_seconds > 0.0).then_some(a.max_seconds),
        corpus_share,
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(a.seed);
    let t0 = std::time::Instant::now();
    let mut curve = Vec::new();
    let mut ema = f64::NAN;
    let steps = ib::train(
        &net,
        &train,
        &settings,
        &mut rng,
        &dev,
        &mut |step, loss, lr| {
            ema = if ema.is_nan() {
                loss
            } else {
                0.95 * ema + 0.05 * loss
            };
            curve.push((step, loss));
            if step % 50 == 0 || step + 1 == settings.steps {
                eprintln!(
                    "step {step:>5}  loss {loss:.5}  (ema {ema:.5})  lr {lr:.2e}  {:.0} s",
                    t0.elapsed().as_secs_f64()
                );
            }
        },
    )?;
    let secs = t0.elapsed().as_secs_f64();
    // Export, load back in tract, check parity, evaluate the export.
    let training = serde_json::json!({"settings": settings, "steps_done": steps, "seconds": secs,
        "init": a.init.as_ref().map(|p| p.display().to_string()),
        "train_clips": train.len(), "val_clips": val.len(),
        "final_loss_ema": ema});
    let mut manifest = ib::export(&net, info, Default::default(), training, &a.out)?;
    let model = Inbetweener::load(&a.out)?;
    let parity = ib::parity(&net, &model, &mut rng)?;
    let rows = ib::evaluate(&model, &train, &val, &a.eval_spacing)?;
    let metrics = &mut manifest.metrics;
    metrics.insert("parity_max_abs".to_string(), parity);
    for r in &rows {
        metrics.insert(format!("val_slerp_cm2_s{}", r.spacing), r.slerp_cm2);
        metrics.insert(
            format!("val_bezier_avg_cm2_s{}", r.spacing),
            r.bezier_avg_cm2,
        );
        metrics.insert(format!("val_learned_cm2_s{}", r.spacing), r.learned_cm2);
    }
    ib::write_manifest(&manifest, &a.out)?;
    let report = serde_json::json!({"parity_max_abs": parity, "steps": steps, "seconds": secs,
        "val_clips": val.iter().map(|c| format!("{}/{}", c.corpus, c.name)).collect::<Vec<_>>(),
        "rows": rows});
    std::fs::write(
        a.out.join("eval.json"),
        serde_json::to_string_pretty(&report)? + "\n",
    )?;
    println!("trained {steps} steps in {secs:.0} s; tract vs candle max |Δ| {parity:.2e}");
    print_inbetween_rows("all held-out clips", &rows);
    Ok(())
}

fn print_inbetween_rows(title: &str, rows: &[choreo::train::inbetween::EvalRow]) {
    println!("{title}: held-out MSE on FK positions, cm² (mean over clips)");
    println!("spacing  clips    slerp  bezier-avg  learned  (bezier fitted to the clip)");
    for r in rows {
        println!(
            "{:>7}  {:>5}  {:>7.3}  {:>10.3}  {:>7.3}  ({:.3})",
            r.spacing, r.clips, r.slerp_cm2, r.bezier_avg_cm2, r.learned_cm2, r.bezier_fit_cm2
        );
    }
}

fn eval_inbetween(model: &Path, d: &DataArgs, spacings: &[usize], json: bool) -> Result<()> {
    use choreo::train::inbetween as ib;
    let model = choreo::lm::inbetween::Inbetweener::load(model)?;
    let dirs = choreo::train::data::corpus_dirs(&d.data, &d.corpora)?;
    let (motions, _) = choreo::train::data::read_motions(&dirs)?;
    let (train, val) = ib::prepare(motions, d.val_fraction, model.config().window + 1, false)?;
    let mut out = Vec::new();
    let mut corpora: Vec<String> = val.iter().map(|c| c.corpus.clone()).collect();
    corpora.dedup();
    for c in corpora {
        let sub: Vec<ib::Clip> = val
            .iter()
            .filter(|x| x.corpus == c)
            .map(|x| ib::Clip {
                corpus: x.corpus.clone(),
                name: x.name.clone(),
                labels: x.labels.clone(),
                motion: x.motion.clone(),
            })
            .collect();
        let rows = ib::evaluate(&model, &train, &sub, spacings)?;
        let names: Vec<String> = sub.iter().map(|x| x.name.clone()).collect();
        if !json {
            print_inbetween_rows(&format!("{c} ({} clips)", sub.len()), &rows);
        }
        out.push(serde_json::json!({"corpus": c, "clips": names, "rows": rows}));
    }
    let rows = ib::evaluate(&model, &train, &val, spacings)?;
    if json {
        out.push(serde_json::json!({"corpus": "all", "rows": rows}));
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_inbetween_rows("all", &rows);
    }
    Ok(())
}
