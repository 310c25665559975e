//! `choreo exemplars`: writes a model's style exemplars (see
//! `choreo::lm::exemplars`) from the training side of corpus folders.

use anyhow::{bail, Context, Result};
use choreo::eval::generate::read_split;
use choreo::lm::exemplars::{Exemplars, SpanChoice};
use choreo::lm::model::MotionModel;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ExemplarsArgs {
    /// The model folder; exemplars.json is written into it.
    #[arg(long, default_value = "models/default")]
    pub model: PathBuf,
    /// Corpus folders (repeatable), each split as the trainer splits it:
    /// only its training sequences give exemplars.
    #[arg(long, required = true)]
    pub data: Vec<PathBuf>,
    /// Seconds per exemplar (at most the model's context).
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// Exemplars per label value.
    #[arg(long, default_value_t = 3)]
    pub per_label: usize,
    /// Label kinds to cover (default: every kind the model is conditioned
    /// on, and the file is written afresh). Named kinds replace only their
    /// own spans: the folder's exemplars for other kinds are kept.
    #[arg(long = "kind")]
    pub kinds: Vec<String>,
    /// How spans are chosen: `heads` keeps, per label value, the spans the
    /// model's own class heads find likeliest to carry it (4 candidate
    /// spans per sequence; the clearest examples); `hash` takes the first
    /// sequences by a hash of their names, one span a third of the way in.
    /// Default: `heads` when the model has class heads, else `hash`.
    #[arg(long, value_parser = ["heads", "hash"])]
    pub choose: Option<String>,
    /// Spread each label value's spans over this kind's values (say
    /// `content`: a style's exemplars then walk, run and wave as its real
    /// takes do) instead of keeping the judge's likeliest spans only.
    #[arg(long)]
    pub cover: Option<String>,
    /// Take each span from the start of its take (its first --seconds)
    /// instead of from inside it: the generation then goes on to what the
    /// take does next (on Bandai, whose runs and raised hands last 2–3 s,
    /// a span from inside such a take ends where it stops).
    #[arg(long)]
    pub from_start: bool,
    /// Choose no spans: take every span of this exemplars.json (another
    /// model's, say the bundled one) and encode it afresh with this
    /// model's vocabulary, from the same --data folders. For a model
    /// whose token layout differs but should seed from the same motion.
    #[arg(long, conflicts_with_all = ["kinds", "cover", "from_start", "choose"])]
    pub same_spans_as: Option<PathBuf>,
}

/// The training side of each corpus folder (the trainer's split), as
/// (name, labels, frame tokens); says on stderr how many each gave.
pub fn training_sequences(
    vocab: &choreo::tokenize::vocab::Vocabulary,
    data: &[PathBuf],
) -> Result<Vec<(String, choreo::motion::Labels, Vec<u32>)>> {
    let mut sequences = Vec::new();
    for d in data {
        let (val, train) = read_split(vocab, d, 0.1, &mut |line| eprintln!("{line}"))
            .with_context(|| format!("--data {}", d.display()))?;
        eprintln!(
            "{}: {} training sequences ({} held out, not used)",
            d.display(),
            train.len(),
            val.len()
        );
        sequences.extend(train.into_iter().map(|c| (c.name, c.labels, c.tokens)));
    }
    Ok(sequences)
}

pub fn run(a: ExemplarsArgs) -> Result<()> {
    let m =
        MotionModel::load(&a.model).with_context(|| format!("--model {}", a.model.display()))?;
    let vocab = m.vocabulary().clone();
    let max_s = m.context_frames() as f64 / vocab.fps;
    if !(a.seconds > 0.0 && a.seconds <= max_s) {
        bail!(
            "--seconds: {} (want 0 < s ≤ {max_s}, the model's context)",
            a.seconds
        );
    }
    if a.per_label == 0 {
        bail!("--per-label must be at least 1");
    }
    let kinds: Vec<String> = if a.kinds.is_empty() {
        m.cond_kinds().to_vec()
    } else {
        for k in &a.kinds {
            if !m.cond_kinds().contains(k) {
                bail!(
                    "--kind {k}: the model is conditioned on {}",
                    m.cond_kinds().join(", ")
                );
            }
        }
        a.kinds.clone()
    };
    let sequences = training_sequences(&vocab, &a.data)?;
    let ex = match &a.same_spans_as {
        Some(from) => {
            let ex = Exemplars::reencoded(from, &sequences, &vocab)
                .with_context(|| format!("--same-spans-as {}", from.display()))?;
            eprintln!("{} spans re-encoded from {}", ex.len(), from.display());
            ex
        }
        None => choose(&a, &m, &vocab, &kinds, &sequences)?,
    };
    ex.save(&a.model).with_context(|| {
        format!(
            "writing {}",
            a.model.join(choreo::lm::exemplars::FILE).display()
        )
    })?;
    let mut covered: std::collections::BTreeMap<&str, std::collections::BTreeSet<&str>> =
        Default::default();
    for it in &ex.items {
        for k in &kinds {
            if let Some(v) = it.labels.get(k) {
                covered.entry(k).or_default().insert(v);
            }
        }
    }
    let summary: Vec<String> = covered
        .iter()
        .map(|(k, vs)| {
            let known = vocab.labels.get(*k).map_or(0, |s| s.len());
            format!("{k} {}/{known}", vs.len())
        })
        .collect();
    println!(
        "{} exemplars of {:.1} s written to {}; label values covered: {}",
        ex.len(),
        ex.seconds,
        a.model.join(choreo::lm::exemplars::FILE).display(),
        summary.join(", ")
    );
    Ok(())
}

/// The spans `choreo exemplars` chooses (by the model's heads or by name
/// hash), with the folder's spans for other kinds kept where `--kind`
/// names only some.
fn choose(
    a: &ExemplarsArgs,
    m: &MotionModel,
    vocab: &choreo::tokenize::vocab::Vocabulary,
    kinds: &[String],
    sequences: &[(String, choreo::motion::Labels, Vec<u32>)],
) -> Result<Exemplars> {
    let heads = m.class_kinds();
    let by_heads = match a.choose.as_deref() {
        Some("heads") if heads.is_empty() => {
            bail!("--choose heads: the model has no class heads (fit them with choreo-train fit-heads)")
        }
        Some("heads") => true,
        Some(_) => false,
        None => !heads.is_empty(),
    };
    if by_heads {
        let unjudged: Vec<&String> = kinds.iter().filter(|k| !heads.contains(k)).collect();
        eprintln!(
            "choosing spans by the model's class heads ({}){}",
            heads.join(", "),
            if unjudged.is_empty() {
                String::new()
            } else {
                format!("; by name hash for {unjudged:?} (no head)")
            }
        );
    }
    let judge = |t: &[u32]| m.classify(t, 1);
    let t0 = std::time::Instant::now();
    if let Some(c) = &a.cover {
        if !sequences.iter().any(|s| s.1.contains_key(c)) {
            bail!("--cover {c}: no training sequence carries a {c} label");
        }
    }
    let mut ex = Exemplars::build(
        sequences,
        vocab,
        kinds,
        a.seconds,
        a.per_label,
        by_heads.then_some(&judge as &choreo::lm::exemplars::Judge<'_>),
        SpanChoice {
            cover: a.cover.as_deref(),
            from_start: a.from_start,
        },
    )
    .context("judging candidate spans")?;
    if by_heads {
        let ps: Vec<f64> = ex
            .items
            .iter()
            .flat_map(|e| e.chosen_for.iter().filter_map(|c| c.p))
            .collect();
        eprintln!(
            "judged in {:.0} s; mean probability of the chosen value {:.2} over {} choices",
            t0.elapsed().as_secs_f64(),
            ps.iter().sum::<f64>() / ps.len().max(1) as f64,
            ps.len()
        );
    }
    if ex.is_empty() {
        bail!("--data: no training sequence carries a label of {kinds:?} the model knows");
    }
    // Named kinds replace only their own spans: the folder's other kinds
    // keep theirs.
    if !a.kinds.is_empty() {
        let old = Exemplars::load(&a.model, vocab).with_context(|| {
            format!(
                "reading the spans of other kinds from {} (remove it to start afresh)",
                a.model.join(choreo::lm::exemplars::FILE).display()
            )
        })?;
        if let Some(old) = old {
            let kept = ex.keep_others(old, kinds);
            eprintln!("kept {kept} spans chosen for other kinds from the previous file");
        }
    }
    Ok(ex)
}
