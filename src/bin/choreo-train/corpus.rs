//! The corpus: what a data folder holds (`survey`), loading it into a
//! vocabulary and a split, and the LDA classifier baseline (`eval-classify`).

use super::*;

pub(crate) fn survey(data: &Path, json: bool) -> Result<()> {
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

pub(crate) fn load_corpus(
    a: &DataArgs,
    vocab: Option<&choreo::tokenize::vocab::Vocabulary>,
    kinds: &[String],
    smpl24: bool,
    fps: f64,
) -> Result<(choreo::tokenize::vocab::Vocabulary, Corpus)> {
    load_corpus_as(a, vocab, kinds, smpl24, fps, None)
}

/// [`load_corpus`], the root velocity slots read in `root_velocity`'s axes
/// where it is given (the vocabulary's own, or world for a new one, where not).
pub(crate) fn load_corpus_as(
    a: &DataArgs,
    vocab: Option<&choreo::tokenize::vocab::Vocabulary>,
    kinds: &[String],
    smpl24: bool,
    fps: f64,
    root_velocity: Option<choreo::tokenize::vocab::RootVelocity>,
) -> Result<(choreo::tokenize::vocab::Vocabulary, Corpus)> {
    let dirs = data::corpus_dirs(&a.data, &a.corpora)?;
    let (motions, info) = data::read_motions(&dirs)?;
    let mut vocab = match vocab {
        Some(v) => v.clone(),
        None => {
            let mut v = data::vocabulary_for(&motions, kinds, smpl24);
            v.fps = fps;
            v
        }
    };
    if let Some(r) = root_velocity {
        vocab.root_velocity = r;
    }
    for c in &a.chain_takes {
        if !a.corpora.contains(c) {
            bail!("--chain-takes: {c:?} is not one of the corpora read (--corpus)");
        }
    }
    let corpus = data::build_chained(
        motions,
        &vocab,
        a.val_fraction,
        !a.no_mirror,
        info,
        &a.chain_takes,
    )?;
    Ok((vocab, corpus))
}

pub(crate) fn eval_classify(ckpt: &Path, a: &DataArgs) -> Result<()> {
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
