//! The frame model's training loop: length-weighted windows from the
//! corpus, the optimisation step, held-out evaluation (bits per frame and
//! class accuracy), resumable checkpoints, and the per-corpus table beside
//! the baselines.

use super::baselines;
use super::data::{self, Corpus, Sequence};
use super::frame::{
    add_context_noise, add_own_samples, batch, example, losses, value_frames, FrameExample,
    FrameNet,
};
use super::model::AdamW;
use super::RunSettings;
use crate::lm::bits_per_frame;
use crate::lm::frame::FrameConfig;
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use anyhow::{bail, Result};
use candle_core::Device;
use rand::rngs::StdRng;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Training sequences as value frames (mirrors beside), with cumulative
/// draw weights: a sequence's frame count times its corpus's weight.
pub struct FrameData {
    pub seqs: Vec<(Vec<u32>, Option<Vec<u32>>, Labels)>,
    pub cum: Vec<usize>,
}

impl FrameData {
    /// Length-weighted draws: every training frame equally likely.
    pub fn new(train: &[Sequence], fl: usize) -> FrameData {
        Self::weighted(train, fl, &BTreeMap::new()).expect("no weights to check")
    }

    /// Draws where each corpus's frames count `weights[corpus]` times (1
    /// for a corpus not named). A name that no training sequence has, or a
    /// weight that is not a positive finite number, is an error naming it.
    pub fn weighted(
        train: &[Sequence],
        fl: usize,
        weights: &BTreeMap<String, f64>,
    ) -> Result<FrameData> {
        Self::balanced(train, fl, weights, None)
    }

    /// [`FrameData::weighted`], and with `balance` = a label kind, the
    /// sequences that carry that kind are drawn so that each of its values
    /// gets the same share of their draws (their total unchanged): a value
    /// whose takes are few or short is drawn as often as a common one.
    /// Sequences without the kind keep their length-weighted share. A kind
    /// that no training sequence carries is an error naming the flag.
    pub fn balanced(
        train: &[Sequence],
        fl: usize,
        weights: &BTreeMap<String, f64>,
        balance: Option<&str>,
    ) -> Result<FrameData> {
        let cum = super::draws::draw_weights(train, fl, weights, balance)?;
        let seqs = train
            .iter()
            .map(|s| {
                (
                    value_frames(&s.tokens, fl),
                    s.mirrored.as_ref().map(|m| value_frames(m, fl)),
                    s.labels.clone(),
                )
            })
            .collect();
        Ok(FrameData { seqs, cum })
    }

    /// Each corpus's share of the draws, for the log.
    pub fn shares(&self, train: &[Sequence]) -> BTreeMap<String, f64> {
        super::draws::shares(train, &self.cum)
    }
}

/// One optimisation step on a fresh batch; returns (nats per frame,
/// frames).
#[allow(clippy::too_many_arguments)]
pub fn train_step(
    net: &FrameNet,
    opt: &mut AdamW,
    vocab: &Vocabulary,
    data: &FrameData,
    window: usize,
    s: &RunSettings,
    rng: &mut StdRng,
    dev: &Device,
) -> Result<(f64, usize)> {
    let c = &net.cfg;
    let as_cls = !c.classes.is_empty() && rng.gen::<f64>() < s.classify_fraction;
    let total = *data.cum.last().expect("training data");
    let mut exs = Vec::with_capacity(s.batch);
    for _ in 0..s.batch {
        let r = rng.gen_range(0..total);
        let i = data.cum.partition_point(|&x| x <= r);
        let (plain, mirror, labels) = &data.seqs[i];
        let values = match (mirror, rng.gen::<bool>()) {
            (Some(m), true) => m,
            _ => plain,
        };
        let n = values.len() / c.slots;
        let w = window.min(n);
        let start = rng.gen_range(0..=n - w);
        let mut ex = example(
            c,
            vocab,
            values,
            start,
            w,
            labels,
            as_cls,
            s.keep_label,
            rng,
        );
        add_context_noise(c, &mut ex, s.context_noise, rng);
        exs.push(ex);
    }
    if !as_cls {
        add_own_samples(net, &mut exs, s.own_context, rng, dev)?;
    }
    let b = batch(c, &exs, dev)?;
    let l = losses(net, &b)?;
    let per_token = (&l.nats / (b.frames * c.slots) as f64)?;
    let nats = l.nats.to_scalar::<f32>()? as f64 / b.frames as f64;
    super::optimise(
        &net.params,
        opt,
        &per_token,
        l.cls.as_ref(),
        s.class_weight,
        nats,
    )?;
    Ok((nats, b.frames))
}

/// Held-out figures: bits per frame over every frame of the validation
/// sequences (windows of the model's context, each with its true history)
/// and class accuracy per kind on the same windows.
pub struct FrameEval {
    pub bits_per_frame: f64,
    pub frames: usize,
    pub accuracy: Vec<(String, f64, usize)>,
}

pub fn evaluate(
    net: &FrameNet,
    vocab: &Vocabulary,
    val: &[Sequence],
    fl: usize,
    max_windows: usize,
    dev: &Device,
) -> Result<FrameEval> {
    evaluate_with(net, vocab, val, fl, max_windows, dev, 1.0, usize::MAX)
}

/// [`evaluate`] with each label kept with probability `keep_label` (0 =
/// every window unlabelled: the gap to 1 is how many bits a frame the
/// labels are worth to the model), on only the first `first` frames of
/// each window (the frames with little or no history; `usize::MAX` =
/// whole windows).
#[allow(clippy::too_many_arguments)]
pub fn evaluate_with(
    net: &FrameNet,
    vocab: &Vocabulary,
    val: &[Sequence],
    fl: usize,
    max_windows: usize,
    dev: &Device,
    keep_label: f64,
    first: usize,
) -> Result<FrameEval> {
    let c = &net.cfg;
    let values: Vec<Vec<u32>> = val.iter().map(|s| value_frames(&s.tokens, fl)).collect();
    let windows: Vec<(usize, usize, usize)> = values
        .iter()
        .enumerate()
        .flat_map(|(i, v)| {
            data::cuts(v.len() / c.slots, c.max_frames)
                .into_iter()
                .map(move |(st, len)| (i, st, len.min(first)))
        })
        .collect();
    let windows = data::spread(windows, max_windows);
    if windows.is_empty() {
        bail!("no validation windows (the split held out nothing)");
    }
    let mut rng = <StdRng as rand::SeedableRng>::seed_from_u64(7);
    let (mut nats, mut frames) = (0f64, 0usize);
    let mut hits = vec![(0usize, 0usize); c.classes.len()];
    for chunk in windows.chunks(8) {
        for as_cls in [false, true] {
            if as_cls && c.classes.is_empty() {
                continue;
            }
            let exs: Vec<FrameExample> = chunk
                .iter()
                .map(|&(i, st, len)| {
                    let l = &val[i].labels;
                    example(
                        c, vocab, &values[i], st, len, l, as_cls, keep_label, &mut rng,
                    )
                })
                .collect();
            let b = batch(c, &exs, dev)?;
            let l = losses(net, &b)?;
            if as_cls {
                for (acc, (a, n)) in hits.iter_mut().zip(l.hits) {
                    acc.0 += a;
                    acc.1 += n;
                }
            } else {
                nats += l.nats.to_scalar::<f32>()? as f64;
                frames += b.frames;
            }
        }
    }
    Ok(FrameEval {
        bits_per_frame: nats / frames.max(1) as f64 / std::f64::consts::LN_2,
        frames,
        accuracy: c
            .classes
            .iter()
            .zip(hits)
            .map(|((k, _), (a, n))| (k.clone(), a as f64 / n.max(1) as f64, n))
            .collect(),
    })
}

/// What a frame-model checkpoint's JSON side holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameState {
    pub config: FrameConfig,
    pub vocabulary: Vocabulary,
    pub settings: RunSettings,
    pub step: usize,
    pub adam_step: usize,
    pub history: Vec<super::LogPoint>,
    pub data: crate::lm::manifest::DataInfo,
    pub metrics: BTreeMap<String, f64>,
    pub train_seconds: f64,
    /// Where a run started with `--init-from` came from: the parent's
    /// steps, training seconds (its own parents included), data and
    /// licences, and its own parent; no paths. None for a run from scratch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<serde_json::Value>,
}

impl FrameState {
    /// The state of a run that has not taken a step.
    pub fn fresh(
        config: FrameConfig,
        vocab: &Vocabulary,
        settings: &RunSettings,
        corpus: &Corpus,
    ) -> FrameState {
        FrameState {
            config,
            vocabulary: vocab.clone(),
            settings: settings.clone(),
            step: 0,
            adam_step: 0,
            history: Vec::new(),
            data: corpus.info.clone(),
            metrics: BTreeMap::new(),
            train_seconds: 0.0,
            parent: None,
        }
    }
}

/// Loads a frame-model checkpoint folder.
pub fn load(dir: &std::path::Path, dev: &Device) -> Result<(FrameState, FrameNet, AdamW)> {
    let (st, t, file): (FrameState, _, _) = super::load_parts(dir, dev)?;
    st.config
        .validate(&dir.join(super::CKPT_JSON).display().to_string())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let net = FrameNet::new(st.config.clone(), dev)?;
    net.params.load_tensors(&t, &file)?;
    let opt = super::restore_adam(&t, &st.settings, st.adam_step);
    Ok((st, net, opt))
}

/// A frame-model run (the trainer's flags): where, the architecture (its
/// `bins`, `slots` and `vocab_size` are taken from the vocabulary) and the
/// schedule.
#[derive(Clone, Debug)]
pub struct FrameRun {
    pub out: std::path::PathBuf,
    pub resume: bool,
    /// On resume: a new total step count (the cosine schedule is recomputed
    /// over it, so a run can be shortened to anneal now, or extended).
    pub resume_steps: Option<usize>,
    /// A new run's starting weights (a frame-model checkpoint folder).
    pub init_from: Option<std::path::PathBuf>,
    pub config: FrameConfig,
    pub settings: RunSettings,
}

/// Trains (or resumes) a frame model on `corpus`, checkpointing into
/// `run.out` at every evaluation and at the end; prints progress lines to
/// standard error and returns the final state.
pub fn run(run: &FrameRun, vocab: &Vocabulary, corpus: &Corpus) -> Result<FrameState> {
    let dev = super::device();
    let fl = vocab.frame_len();
    let (mut st, net, mut opt) = if run.resume {
        let (mut st, net, opt) = load(&run.out, &dev)?;
        if let Some(n) = run.resume_steps {
            st.settings.steps = n;
        }
        st.settings.max_seconds = run.settings.max_seconds;
        if !run.settings.corpus_weights.is_empty() {
            st.settings.corpus_weights = run.settings.corpus_weights.clone();
        }
        if run.settings.balance.is_some() {
            st.settings.balance = run.settings.balance.clone();
        }
        (st, net, opt)
    } else {
        let cfg = FrameConfig {
            bins: vocab.bins,
            slots: fl - 1,
            vocab_size: vocab.size(),
            ..run.config.clone()
        };
        cfg.validate("--frame flags")
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let net = FrameNet::new(cfg.clone(), &dev)?;
        let mut parent = None;
        if let Some(from) = &run.init_from {
            let (_, t, file, lineage) = super::frame_init::init_source(from, &dev)?;
            parent = Some(lineage);
            let fresh = net.params.load_matching(&t, &file)?;
            tracing::info!(
                "started from {}; fresh parameters: {}",
                from.display(),
                if fresh.is_empty() {
                    "none".to_string()
                } else {
                    fresh.join(", ")
                }
            );
            // Blocks the parent lacks (a deeper model grown from it) start
            // as the identity, so the grown model begins where its parent
            // ended.
            let grown = net.params.zero_fresh_blocks(&fresh)?;
            if !grown.is_empty() {
                tracing::info!("new blocks, starting as the identity: {}", grown.join(", "));
            }
        }
        let mut st = FrameState::fresh(cfg, vocab, &run.settings, corpus);
        st.parent = parent;
        let opt = AdamW::new(run.settings.lr, run.settings.weight_decay);
        (st, net, opt)
    };
    let s = st.settings.clone();
    let data = FrameData::balanced(&corpus.train, fl, &s.corpus_weights, s.balance.as_deref())?;
    super::draws::log_shares(&corpus.train, &data.cum);
    tracing::info!(
        "frame model: {} parameters; global d {} × {} layers, local d {} × {} layers, context {} frames, change radius {}",
        net.params.count(),
        net.cfg.d_global,
        net.cfg.global_layers,
        net.cfg.d_local,
        net.cfg.local_layers,
        net.cfg.max_frames,
        net.cfg.radius
    );
    let mut rng = <StdRng as rand::SeedableRng>::seed_from_u64(s.seed.wrapping_add(st.step as u64));
    std::fs::create_dir_all(&run.out)?;
    let t0 = std::time::Instant::now();
    let spent = st.train_seconds;
    let (mut acc, mut n_acc, mut frames_acc) = (0f64, 0usize, 0usize);
    let mut t_win = std::time::Instant::now();
    while st.step < s.steps {
        if s.max_seconds > 0.0 && spent + t0.elapsed().as_secs_f64() > s.max_seconds {
            tracing::info!("time limit reached at step {}", st.step);
            break;
        }
        opt.lr = super::lr_at(&s, st.step);
        let (nats, frames) = train_step(
            &net,
            &mut opt,
            vocab,
            &data,
            net.cfg.max_frames,
            &s,
            &mut rng,
            &dev,
        )?;
        st.step += 1;
        acc += nats;
        n_acc += 1;
        frames_acc += frames;
        if st.step % s.eval_every == 0 || st.step == s.steps {
            let fps = frames_acc as f64 / t_win.elapsed().as_secs_f64().max(1e-9);
            let ev = evaluate(&net, vocab, &corpus.val, fl, 48, &dev)?;
            let acc_s: Vec<String> = ev
                .accuracy
                .iter()
                .map(|(k, a, n)| format!("{k} {:.1}% of {n}", 100.0 * a))
                .collect();
            tracing::info!(
                "step {:>6}  lr {:.2e}  train {:.1} bits/frame  val {:.1} bits/frame  {:.0} frames/s ({:.0} tokens/s)  {}",
                st.step,
                opt.lr,
                acc / n_acc as f64 / std::f64::consts::LN_2,
                ev.bits_per_frame,
                fps,
                fps * fl as f64,
                acc_s.join("  ")
            );
            st.history.push(super::LogPoint {
                step: st.step,
                lr: opt.lr,
                train_loss: acc / n_acc as f64 / fl as f64,
                val_loss: Some(ev.bits_per_frame * std::f64::consts::LN_2 / fl as f64),
                val_bits_per_frame: Some(ev.bits_per_frame),
                tokens_per_s: fps * fl as f64,
            });
            st.adam_step = opt.step;
            st.train_seconds = spent + t0.elapsed().as_secs_f64();
            super::save_parts(&run.out, &net.params, &opt, &st)?;
            (acc, n_acc, frames_acc) = (0.0, 0, 0);
            t_win = std::time::Instant::now();
        }
    }
    st.train_seconds = spent + t0.elapsed().as_secs_f64();
    let ev = evaluate(&net, vocab, &corpus.val, fl, usize::MAX, &dev)?;
    st.metrics
        .insert("val_bits_per_frame".into(), ev.bits_per_frame);
    st.metrics.insert("val_frames".into(), ev.frames as f64);
    st.metrics
        .insert("parameters".into(), net.params.count() as f64);
    st.metrics.insert("train_seconds".into(), st.train_seconds);
    for (k, a, n) in &ev.accuracy {
        st.metrics.insert(format!("val_accuracy_{k}"), *a);
        st.metrics.insert(format!("val_windows_{k}"), *n as f64);
    }
    st.adam_step = opt.step;
    super::save_parts(&run.out, &net.params, &opt, &st)?;
    Ok(st)
}

/// Per held-out corpus (and over all): the frame model's bits/frame beside
/// the unigram, per-slot unigram and previous-frame delta baselines (fitted
/// on all training sequences), and its class accuracy beside LDA and the
/// majority class on windows of its context (thesis Table 4.8's shape).
pub fn table(
    net: &FrameNet,
    vocab: &Vocabulary,
    corpus: &Corpus,
) -> Result<Vec<serde_json::Value>> {
    let dev = super::device();
    let fl = vocab.frame_len();
    let mut names: Vec<String> = corpus.val.iter().map(|s| s.corpus.clone()).collect();
    names.sort();
    names.dedup();
    names.push("all".into());
    // The classifiers' training windows are the same for every row.
    let train_windows = data::context_windows(&corpus.train, fl, net.cfg.max_frames);
    let mut rows = Vec::new();
    for name in names {
        let val: Vec<Sequence> = corpus
            .val
            .iter()
            .filter(|s| name == "all" || s.corpus == name)
            .map(|s| Sequence {
                mirrored: None,
                tokens: s.tokens.clone(),
                labels: s.labels.clone(),
                name: s.name.clone(),
                corpus: s.corpus.clone(),
            })
            .collect();
        let ev = evaluate(net, vocab, &val, fl, usize::MAX, &dev)?;
        let with = |keep, first| evaluate_with(net, vocab, &val, fl, usize::MAX, &dev, keep, first);
        let unlabelled = with(0.0, usize::MAX)?;
        let (start_l, start_u) = (with(1.0, 10)?, with(0.0, 10)?);
        let val_windows = data::context_windows(&val, fl, net.cfg.max_frames);
        let classes: Vec<serde_json::Value> = net
            .cfg
            .classes
            .iter()
            .zip(&ev.accuracy)
            .filter(|(_, (_, _, n))| *n > 0)
            .map(|((k, values), (_, acc, n))| {
                let (major, lda, _) = baselines::classification_baselines(
                    &train_windows,
                    &val_windows,
                    k,
                    values,
                    fl,
                    vocab.bins,
                );
                serde_json::json!({"kind": k, "windows": n, "model": acc, "lda": lda, "majority": major})
            })
            .collect();
        let (uni, slot) = baselines::unigram_losses(&corpus.train, &val, vocab.size(), fl);
        let delta = bits_per_frame(
            baselines::delta_loss(&corpus.train, &val, vocab.size(), vocab.bins, fl),
            fl,
        );
        rows.push(serde_json::json!({
            "corpus": name,
            "val_sequences": val.len(),
            "val_frames": ev.frames,
            "frame_model_bits_per_frame": ev.bits_per_frame,
            "delta_bits_per_frame": delta,
            "slot_unigram_bits_per_frame": bits_per_frame(slot, fl),
            "unigram_bits_per_frame": bits_per_frame(uni, fl),
            "ratio_to_delta": ev.bits_per_frame / delta,
            "unlabelled_bits_per_frame": unlabelled.bits_per_frame,
            "label_bits_per_frame": unlabelled.bits_per_frame - ev.bits_per_frame,
            "first10_bits_per_frame": start_l.bits_per_frame,
            "first10_label_bits_per_frame": start_u.bits_per_frame - start_l.bits_per_frame,
            "classification": classes,
        }));
    }
    Ok(rows)
}
