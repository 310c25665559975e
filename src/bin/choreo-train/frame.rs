//! The frame model: its flags, training (the loop is `choreo::train::frame_run`),
//! export with its parity check, and the per-corpus table.

use super::*;

/// `choreo-train frame`'s flags.
#[derive(Args, Clone)]
pub(crate) struct FrameArgs {
    #[command(flatten)]
    data: DataArgs,
    /// Output folder: checkpoint (resumable) and the final metrics.
    #[arg(long)]
    out: PathBuf,
    /// Continue the run saved in --out.
    #[arg(long)]
    resume: bool,
    /// Start a new run from the weights of this frame-model checkpoint
    /// folder, or of an exported model folder such as models/default (its
    /// vocabulary too; an export's fitted class heads are not taken);
    /// parameters it lacks keep their fresh initialisation (e.g.
    /// `g_cond_all` when adding --cond-every), except whole blocks it
    /// lacks (more --global-layers or --local-layers than the parent):
    /// those start as the identity, so the deeper model begins where
    /// its parent ended.
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
    /// The axes of the root velocity slots: `world` (the scene's x, z) or
    /// `heading` (sideways, forward in the pelvis's heading). With
    /// --init-from it re-expresses the parent's slots (the weights then
    /// relearn what the two slots mean). Default: the parent's, or world.
    #[arg(long, value_parser = choreo::tokenize::vocab::RootVelocity::parse)]
    root_velocity: Option<choreo::tokenize::vocab::RootVelocity>,
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
    /// Draw this corpus's training frames W times as often as a length-
    /// weighted draw would (NAME=W, repeatable; e.g. `--corpus-weight
    /// bandai=2`). The held-out sets are unchanged.
    #[arg(long = "corpus-weight", value_name = "NAME=W")]
    corpus_weight: Vec<String>,
    /// Draw the sequences that carry this label kind so that each of its
    /// values gets the same share of their draws (e.g. `--balance content`:
    /// Bandai's runs and raised hands, short takes, as often as its walks).
    #[arg(long, value_name = "KIND")]
    balance: Option<String>,
    /// Train on noisy history: each training window draws a noise level
    /// up to this many bins (a standard deviation; 1 bin = 1° of a joint
    /// angle) and every context frame the network reads (the global
    /// input and the local decoder's previous frames) gets that much
    /// Gaussian noise per slot, while the frame to predict stays true; the
    /// model learns to go on from imperfect history, as it must from its
    /// own samples. Held-out bits are scored on clean context. 0 = off.
    #[arg(long, default_value_t = 0.0, value_parser = non_negative)]
    context_noise: f64,
    /// Train on the model's own samples (parallel scheduled sampling):
    /// before each step the network reads the batch once, draws every
    /// frame's next frame from its own distribution, and this share of
    /// the context frames (0–1) is replaced by those draws while the
    /// targets stay true. One more forward pass a step. 0 = off.
    #[arg(long, default_value_t = 0.0, value_parser = share)]
    own_context: f64,
}

fn share(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        _ => Err(format!("{s:?} is not a share between 0 and 1")),
    }
}

fn non_negative(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("{s:?} is not a finite number ≥ 0")),
    }
}

pub(crate) fn frame(a: FrameArgs, engine: &choreo::lm::engine::Engine) -> Result<()> {
    let mut kinds = a.cond.clone();
    for k in &a.classify {
        if !kinds.contains(k) {
            kinds.push(k.clone());
        }
    }
    let known = if let Some(from) = &a.init_from {
        Some(tr::frame::init_source(from, &tr::device())?.0)
    } else if a.resume {
        let (st, _, _): (tr::frame::FrameState, _, _) = tr::load_parts(&a.out, &tr::device())?;
        Some(st.vocabulary)
    } else {
        None
    };
    if a.resume && a.root_velocity.is_some() {
        bail!("--root-velocity: a resumed run keeps its own vocabulary's");
    }
    let (vocab, corpus) = load_corpus_as(
        &a.data,
        known.as_ref(),
        &kinds,
        false,
        a.fps,
        a.root_velocity,
    )?;
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
            corpus_weights: parse_corpus_weights(&a.corpus_weight)?,
            balance: a.balance.clone(),
            context_noise: a.context_noise,
            own_context: a.own_context,
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

/// `--corpus-weight NAME=W` values as a map (a name given twice, or a
/// value that is not `NAME=number`, is an error naming the flag).
pub(crate) fn parse_corpus_weights(
    given: &[String],
) -> Result<std::collections::BTreeMap<String, f64>> {
    let mut out = std::collections::BTreeMap::new();
    for g in given {
        let (name, w) = g.split_once('=').with_context(|| {
            format!("--corpus-weight: {g:?} is not NAME=WEIGHT (e.g. bandai=2)")
        })?;
        let w: f64 = w
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("--corpus-weight: the weight in {g:?} is not a number"))?;
        if out.insert(name.trim().to_string(), w).is_some() {
            bail!("--corpus-weight: corpus {name:?} is given twice");
        }
    }
    Ok(out)
}

/// Exports a frame model and checks the export against the trainer on the
/// first held-out sequence.
pub(crate) fn export_frame(
    net: &tr::frame::FrameNet,
    vocab: &choreo::tokenize::vocab::Vocabulary,
    corpus: &Corpus,
    st: &tr::frame::FrameState,
    dir: &Path,
    engine: &choreo::lm::engine::Engine,
) -> Result<()> {
    let mut training = serde_json::json!({
        "steps": st.step,
        "settings": st.settings,
        "train_seconds": st.train_seconds,
        "history": st.history,
    });
    let mut data = st.data.clone();
    if let Some(p) = &st.parent {
        training["parent"] = p.clone();
        training["total_train_seconds"] =
            (st.train_seconds + tr::frame::lineage_seconds(Some(p))).into();
        data.licences = tr::frame::licences_with_parents(&st.data, Some(p));
    }
    let m = tr::frame_export::export(net, vocab, data, st.metrics.clone(), training, dir)?;
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
pub(crate) fn print_frame_table(
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

pub(crate) fn fit_heads(
    model: &Path,
    data: &DataArgs,
    out: Option<&Path>,
    threads: usize,
    mirrors: bool,
    classify: &[String],
    engine: &choreo::lm::engine::Engine,
) -> Result<()> {
    let staged = with_head_slots(model, classify, engine)?;
    let result = fit_heads_on(
        staged.as_deref().unwrap_or(model),
        data,
        out,
        threads,
        mirrors,
        engine,
    );
    if let Some(dir) = staged {
        std::fs::remove_dir_all(dir)?;
    }
    result
}

/// [`fit_heads`] on a model that has its head slots.
fn fit_heads_on(
    model: &Path,
    data: &DataArgs,
    out: Option<&Path>,
    threads: usize,
    mirrors: bool,
    engine: &choreo::lm::engine::Engine,
) -> Result<()> {
    use choreo::train::frame_heads as fh;
    const HEAD: fh::Features = fh::Features::StateAndPose;
    let session = choreo::lm::frame_runtime::FrameSession::load_with(model, engine)?;
    if session.config().classes.is_empty() {
        bail!(
            "{}: the model has no class heads; name the label kinds to fit with --classify (e.g. --classify genre --classify style)",
            model.display()
        );
    }
    let vocab = session.manifest.vocabulary.clone();
    let (vocab, corpus) = load_corpus(data, Some(&vocab), &[], false, vocab.fps)?;
    let fl = vocab.frame_len();
    let t0 = Instant::now();
    let train = fh::read_windows(&session, &corpus.train, fl, vocab.bins, mirrors, threads)?;
    let held_out = fh::read_windows(&session, &corpus.val, fl, vocab.bins, false, threads)?;
    eprintln!(
        "read {} training windows{} and {} held-out windows through the model in {:.0} s",
        train.len(),
        if mirrors { " (mirrors included)" } else { "" },
        held_out.len(),
        t0.elapsed().as_secs_f64()
    );
    let (kinds, heads) = fh::fit_heads(&session, &train, &held_out, HEAD)?;
    let mut head = String::from("| kind | train / held-out windows | majority | current head |");
    for (f, baseline) in fh::METHODS {
        head += &format!(
            " {}{} |",
            f.name(),
            if baseline { " (Table 4.8 LDA)" } else { "" }
        );
    }
    eprintln!("{head}");
    eprintln!("|{}", "---|".repeat(4 + fh::METHODS.len()));
    for k in &kinds {
        let mut row = format!(
            "| {} | {} / {} | {:.1} | {:.1} |",
            k.kind,
            k.train_windows,
            k.held_out_windows,
            100.0 * k.majority,
            100.0 * k.current_head
        );
        for s in &k.methods {
            row += &format!(
                " {:.1} (cv {:.1}, γ {}) |",
                100.0 * s.held_out,
                100.0 * s.train_cv,
                s.shrink
            );
        }
        eprintln!("{row}");
    }
    for k in &kinds {
        if let Some(c) = &k.calibration {
            eprintln!(
                "{}: head on {}; temperature {:.2} (out-of-fold log-loss {:.3} nats, untempered {:.3}); held out {:.1}",
                k.kind,
                k.head_features,
                c.temperature,
                c.cv_log_loss,
                c.cv_log_loss_untempered,
                100.0 * k.new_head
            );
        }
    }
    let report = serde_json::json!({
        "method": "shrunk LDA on each 200-frame window's mean global state (read unconditioned through the exported graph) and per-step pose statistics of the graph's own inputs (per slot: mean bin, mean squared bin, mean change magnitude); shrinkage by 5-fold cross-validation grouped by sequence",
        "head_features": HEAD.name(),
        "train_windows": train.len(),
        "mirrors": mirrors,
        "held_out_windows": held_out.len(),
        "corpora": corpus.info.corpora,
        "kinds": kinds,
    });
    if let Some(out) = out {
        fh::write_model(model, out, &heads, &report, &held_out, HEAD, engine)?;
        eprintln!(
            "wrote {} (its classify checked against the fit on every held-out window)",
            out.display()
        );
    }
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}

/// A temporary copy of `model` with head slots for the kinds `classify`
/// names (see `frame_heads::add_head_slots`); None when it has them.
fn with_head_slots(
    model: &Path,
    classify: &[String],
    engine: &choreo::lm::engine::Engine,
) -> Result<Option<PathBuf>> {
    let dir = std::env::temp_dir().join(format!("choreo-fit-heads-{}", std::process::id()));
    if !choreo::train::frame_heads::add_head_slots(model, classify, &dir, engine)? {
        return Ok(None);
    }
    eprintln!(
        "{}: head slots for {} added (the other weights read back and written unchanged)",
        model.display(),
        classify.join(", ")
    );
    Ok(Some(dir))
}
