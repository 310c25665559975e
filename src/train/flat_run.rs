//! The thesis's flat GPT: its training loop (scratch, fine-tune, resume,
//! learning-rate sweep), checkpoints, history plot and export. The trainer
//! binary (`choreo-train train`) only turns its flags into a [`FlatRun`].

use super::data::Corpus;
use super::model::{AdamW, Gpt};
use super::{baselines, CheckpointState, LogPoint, RunSettings};
use crate::lm::{bits_per_frame, ModelConfig, Objective, PosScheme};
use crate::plot::{render_png, Chart, Line, PALETTE};
use crate::tokenize::vocab::Vocabulary;
use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use rand::rngs::StdRng;
use rand::SeedableRng;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One flat-GPT run: where it writes, where it starts from, the
/// architecture (for a run from scratch) and the schedule.
#[derive(Clone, Debug)]
pub struct FlatRun {
    /// Output folder: checkpoint, log, loss curve, export/.
    pub out: PathBuf,
    /// Fine-tune from this checkpoint folder (its vocabulary and architecture).
    pub init: Option<PathBuf>,
    /// Continue the run saved in `out`.
    pub resume: bool,
    pub d_model: usize,
    pub layers: usize,
    pub heads: usize,
    /// Frames per context window.
    pub frames: usize,
    pub positions: PosScheme,
    pub objective: Objective,
    /// 13 (the thesis's simplification) or 24 SMPL joints.
    pub joints: usize,
    /// Label kinds the prefix may carry.
    pub cond: Vec<String>,
    /// Label kinds to learn class heads for (none = no heads).
    pub classify: Vec<String>,
    /// Total steps: a new run's (None = 2000), or on resume a new total
    /// (the cosine schedule is recomputed over it, so a run can be
    /// extended, or shortened to anneal now; None = the run's own).
    pub steps: Option<usize>,
    pub batch: usize,
    pub lr: f64,
    pub dropout: f32,
    pub eval_every: usize,
    pub seed: u64,
    /// Stop after this many seconds (0 = run all steps).
    pub max_seconds: f64,
    /// Per corpus, how many times as often its training frames are drawn
    /// as a length-weighted draw would (empty = every frame alike). A
    /// resumed run keeps its own unless new ones are given.
    pub corpus_weights: std::collections::BTreeMap<String, f64>,
    /// Export ONNX + manifest to `out/export` at the end.
    pub export: bool,
    /// Instead of training: sweep the learning rate from 1e-6 to 1 over
    /// `steps` steps and plot the loss (thesis Fig. 4.9).
    pub lr_sweep: bool,
}

pub fn training_json(st: &CheckpointState) -> serde_json::Value {
    serde_json::json!({
        "regime": st.regime,
        "parent": st.parent,
        "steps": st.step,
        "settings": st.settings,
        "final": st.history.last(),
    })
}

pub fn train(
    a: &FlatRun,
    load: impl FnOnce(Option<&Vocabulary>, &[String]) -> Result<(Vocabulary, Corpus)>,
    engine: &crate::lm::engine::Engine,
) -> Result<serde_json::Value> {
    let dev = super::device();
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
        Some(super::load_checkpoint(&a.out, &dev)?)
    } else {
        None
    };
    let init_state = match (&a.init, &resume_state) {
        (Some(p), None) => Some(super::load_checkpoint(p, &dev)?),
        _ => None,
    };
    let known_vocab = resume_state
        .as_ref()
        .or(init_state.as_ref())
        .map(|s| s.0.vocabulary.clone());
    let (vocab, corpus) = load(known_vocab.as_ref(), &kinds)?;
    let fl = vocab.frame_len();
    tracing::info!(
        "data: {} files from {:?}; {} train / {} validation sequences; {} training tokens (mirrors included); read in {:.1} s",
        corpus.info.files,
        corpus.info.corpora,
        corpus.info.train_sequences,
        corpus.info.val_sequences,
        corpus.info.train_tokens,
        t0.elapsed().as_secs_f64()
    );
    let steps = a.steps.unwrap_or(2000);
    let settings = RunSettings {
        steps,
        batch: a.batch,
        lr: a.lr,
        min_lr_ratio: 0.1,
        warmup: (steps / 20).max(1),
        weight_decay: 0.1,
        dropout: a.dropout,
        eval_every: a.eval_every.max(1),
        seed: a.seed,
        keep_label: 0.8,
        classify_fraction: if a.classify.is_empty() { 0.0 } else { 0.5 },
        class_weight: 1.0,
        mask_rate: 0.15,
        corpus_weights: a.corpus_weights.clone(),
        balance: None,
        context_noise: 0.0,
        own_context: 0.0,
        max_seconds: a.max_seconds,
    };
    let (mut state, model, mut opt) = match (resume_state, init_state) {
        (Some((mut st, m, o)), _) => {
            // The saved schedule, with the new total and time limit asked for.
            if let Some(n) = a.steps {
                st.settings.steps = n;
            }
            st.settings.max_seconds = a.max_seconds;
            if !a.corpus_weights.is_empty() {
                st.settings.corpus_weights = a.corpus_weights.clone();
            }
            (st, m, o)
        }
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
                positions: a.positions,
                objective: a.objective,
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
    tracing::info!(
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
    // Length-weighted draws, each corpus's frames counted as often as its
    // weight says (the frame trainer's draws).
    let cum = super::draws::draw_weights(&corpus.train, fl, &s.corpus_weights, None)?;
    if !s.corpus_weights.is_empty() {
        super::draws::log_shares(&corpus.train, &cum);
    }
    let mut rng = StdRng::seed_from_u64(s.seed.wrapping_add(state.step as u64));
    std::fs::create_dir_all(&a.out)?;

    if a.lr_sweep {
        return lr_sweep(a, &model, &vocab, &corpus, &cum, &s, &mut rng);
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
        opt.lr = super::lr_at(&s, state.step);
        let (loss, toks) =
            super::train_step(&model, &mut opt, &vocab, &corpus, &cum, &s, &mut rng, &dev)?;
        state.step += 1;
        tok_acc += toks;
        tokens_total += toks;
        loss_acc += loss;
        n_acc += 1;
        let tps = tok_acc as f64 / t_win.elapsed().as_secs_f64().max(1e-9);
        pb.set_message(format!("loss {loss:.3} · {tps:.0} tok/s"));
        pb.set_position(state.step as u64);
        if state.step % s.eval_every == 0 || state.step == s.steps {
            let ev = super::evaluate(&model, &vocab, &corpus, s.batch, &dev)?;
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
            super::save_checkpoint(&a.out, &model, &opt, &state)?;
            plot_history(&state.history, &a.out.join("loss.png"))?;
            (tok_acc, loss_acc, n_acc) = (0, 0.0, 0);
            t_win = Instant::now();
        }
    }
    pb.finish_and_clear();
    let secs = t_train.elapsed().as_secs_f64();
    // Final held-out figures and the unigram floor on the same tokens.
    let ev = super::evaluate(&model, &vocab, &corpus, s.batch, &dev)?;
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
    super::save_checkpoint(&a.out, &model, &opt, &state)?;
    plot_history(&state.history, &a.out.join("loss.png"))?;
    let report = serde_json::json!({
        "out": a.out.display().to_string(),
        "regime": state.regime,
        "steps": state.step,
        "metrics": state.metrics,
    });
    if a.export {
        let dir = a.out.join("export");
        let mf = super::export::export(
            &model,
            &vocab,
            state.data.clone(),
            state.metrics.clone(),
            training_json(&state),
            &dir,
        )?;
        let r = super::parity::check(&model, &vocab, &dir, s.seed + 1, engine)?;
        tracing::info!("exported {} to {}; {r}", mf.onnx, dir.display());
    }
    Ok(report)
}

/// A log line above the bar, or on standard error when there is no bar
/// (not a terminal).
pub fn say(pb: &ProgressBar, line: String) {
    if pb.is_hidden() {
        tracing::info!("{line}");
    } else {
        pb.println(line);
    }
}

/// The state of a run that has not taken a step yet.
pub fn new_state(
    config: ModelConfig,
    vocab: &Vocabulary,
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
pub fn known_kinds(vocab: &Vocabulary, kinds: &[String]) -> Vec<String> {
    kinds
        .iter()
        .filter(|k| vocab.labels.contains_key(*k))
        .cloned()
        .collect()
}

pub fn class_values(vocab: &Vocabulary, kinds: &[String]) -> Result<Vec<(String, Vec<String>)>> {
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

pub fn plot_history(h: &[LogPoint], path: &Path) -> Result<()> {
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
pub fn lr_sweep(
    a: &FlatRun,
    model: &Gpt,
    vocab: &Vocabulary,
    corpus: &Corpus,
    cum: &[usize],
    s: &RunSettings,
    rng: &mut StdRng,
) -> Result<serde_json::Value> {
    let dev = super::device();
    let mut opt = AdamW::new(1e-6, s.weight_decay);
    let (lo, hi) = (1e-6f64, 1.0f64);
    let mut pts = Vec::new();
    let mut smooth = None;
    let mut best = f64::INFINITY;
    for i in 0..s.steps {
        let lr = lo * (hi / lo).powf(i as f64 / (s.steps - 1).max(1) as f64);
        opt.lr = lr;
        let (loss, _) = match super::train_step(model, &mut opt, vocab, corpus, cum, s, rng, &dev) {
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
        tracing::info!("lr {lr:.2e}  loss {loss:.4}  smoothed {sm:.4}");
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
    // The thesis's rule: a tenth of where the loss turns up.
    Ok(serde_json::json!({
        "loss_turns_up_near_lr": turn,
        "suggested_lr": turn / 10.0,
    }))
}
