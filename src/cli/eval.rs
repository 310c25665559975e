//! `choreo eval …`: the evaluations that reproduce the theses' tables.

use super::args::*;
use anyhow::{bail, Context, Result};
use choreo::eval::query as eval_q;
use choreo::features::Embedding;
use clap::Subcommand;
use serde_json::json;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum EvalCmd {
    /// Generated motion against held-out real clips of each label: FID_k,
    /// FID_g, acceleration / jerk / skating ratios, frozen fraction,
    /// diversity and conditioning accuracy (an LDA judge fitted on real
    /// training windows), one row per sampling setting.
    Generate {
        #[arg(long, default_value = "models/default")]
        model: PathBuf,
        /// A folder of clips (the trainer's split: the first 10 % by name
        /// hash are held out).
        #[arg(long)]
        data: PathBuf,
        /// The label kind to condition on (e.g. genre, style).
        #[arg(long)]
        labels: String,
        #[arg(long, default_value_t = 3)]
        per_label: usize,
        /// Generated clips' length, and the longest real segment (longer
        /// held-out takes are cut into pieces of this length).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// `fixed`: every generated clip lasts --seconds; `held-out`: the
        /// k-th clip of a label lasts as long as that label's k-th held-out
        /// segment (cycled), so both sides hold the same mix of lengths
        /// (a short take's features average over fewer frames).
        #[arg(long, default_value = "fixed")]
        lengths: String,
        /// Sampling settings, T:K:P[:G[:N[:J[:W[:C[:D[:A[:R[:E[:M[:V[:S]]]]]]]]]]]] (temperature:top_k:top_p
        /// [:guidance[:keep_near[:max_jump[:posture[:context[:draws[:pace[:jerk[:ease[:matching[:travel[:skate]]]]]]]]]]]]), greedy,
        /// or `default`: what a request for the label kind naming no
        /// sampling gets (the model's per-kind defaults filled in). J `auto`
        /// takes the model's default for the label kind, as a request naming
        /// no max_jump gets.
        #[arg(long, value_delimiter = ',', default_values_t = ["greedy", "1:0:1", "0.9:0:0.95", "0.8:0:0.9"].map(String::from).to_vec())]
        sampling: Vec<String>,
        /// Seed each clip with one of the model's style exemplars of the
        /// label (`auto`, what the API does), from nothing (`none`), or
        /// both rows side by side.
        #[arg(long, default_value = "both")]
        exemplar: String,
        /// Best of N: each clip is the one of N samples the model's class
        /// heads find likeliest to carry its label (what a request's
        /// `candidates` does); a list runs each row once per entry.
        #[arg(long, value_delimiter = ',', default_values_t = [1u32])]
        candidates: Vec<u32>,
        /// With more than one candidate: rank continuations of this many
        /// frames while the clip is made and go on from the best (what a
        /// request's `rank_every` does); 0 ranks whole clips.
        #[arg(long, default_value_t = 0)]
        rank_every: usize,
        /// The generated root's ground path, named as a request's `root`
        /// names it: as the model's tokens carry it (`model`), rebuilt from
        /// foot contact (`feet`), or `both` rows from the same clips.
        #[arg(long, default_value = "model")]
        root: String,
        /// The legs, named as a request's `feet` names them: as the model
        /// made them (`model`), with the feet pinned where they touch the
        /// floor (`pin`, leg IK), or `both` rows from the same clips.
        #[arg(long, default_value = "model")]
        feet: String,
        /// The first clip's sampling seed (clip i of a label uses seed + i):
        /// another seed draws another set of clips, to see how far a row
        /// moves with the draw.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long)]
        json: bool,
    },
    /// Keypoints from video: IK accuracy per joint (clean and noisy
    /// keypoints made from real takes, rest pose beside) and cross-modal
    /// search recall (keypoint versions against the mocap, both ways).
    Footage(super::footage::EvalArgs),
    /// Thesis 000 Table 3.2 protocol on a corpus: every window a query,
    /// same-sequence neighbours excluded (or, --same-sequence allow, the
    /// thesis's own protocol), k = 10, majority vote, entropy (bans), and
    /// the majority class beside.
    Query {
        #[arg(long)]
        data: Vec<PathBuf>,
        /// Label kinds to score, comma-separated (e.g. content,style or genre,dancer).
        #[arg(long, value_delimiter = ',', required = true)]
        labels: Vec<String>,
        /// Embeddings to evaluate: stft, dct, pca, pose, lm (default: the
        /// three spectral ones; lm needs --model).
        #[arg(long, value_delimiter = ',')]
        embedding: Vec<String>,
        #[arg(long, default_value_t = 32)]
        hop: usize,
        #[arg(long, default_value_t = 10)]
        k: usize,
        /// exclude: no neighbour from the query's own sequence (strict);
        /// allow: any window but the query itself (the thesis's protocol).
        #[arg(long, default_value = "exclude")]
        same_sequence: eval_q::SameSequence,
        /// all: every window is a query; held-out: only windows of the
        /// trainer's held-out sequences (per --data folder, 10 % by name
        /// hash), which a model trained on that corpus never saw.
        #[arg(long, default_value = "all")]
        queries: eval_q::Queries,
        /// A frame model folder, for the lm embedding.
        #[arg(long)]
        model: Option<PathBuf>,
        /// Sequence whitening with this many directions (0 = off): each
        /// embedding is mapped onto the directions that separate sequences
        /// from one another (no labels used), fitted on the training
        /// sequences only; needs --queries held-out. Embeddings over 2,048
        /// values (STFT) are left out.
        #[arg(long, default_value_t = 0)]
        whiten: usize,
        /// What --whiten separates: sequence (no labels), or a label kind
        /// (a supervised LDA on that label's values, fitted on the training
        /// sequences: the fair comparator of an embedding trained with labels).
        #[arg(long, default_value = "sequence")]
        whiten_by: eval_q::WhitenBy,
        #[arg(long)]
        json: bool,
    },
    /// Thesis 000 Tables 3.3/3.4 over pairs drawn from a corpus (fixed seed):
    /// every objective, cosine similarities of STFT embeddings, jitter.
    Interpolate {
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        #[arg(long, default_value_t = 10)]
        pairs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "0:8", value_parser = parse_range)]
        band: (usize, usize),
        #[arg(long, default_value_t = 300)]
        steps: usize,
        #[arg(long, default_value_t = 0.02)]
        lr: f64,
        /// Repair short capture glitches first (see `interpolate --despike`).
        #[arg(long)]
        despike: bool,
        #[arg(long)]
        json: bool,
    },
    /// Thesis 001 Tables 4.1–4.7 protocol: clips cut into 4/4 measures at
    /// their tempo, N keyframes per measure, MSE / FID_k / FID_g.
    Keyframes {
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Tempo for clips without a tempo label.
        #[arg(long, default_value_t = 120.0)]
        bpm: f64,
        #[arg(long, value_delimiter = ',', default_value = "3,5,9")]
        counts: Vec<usize>,
        #[arg(long)]
        json: bool,
    },
    /// Thesis 000 Tables 4.1, 4.2 and Figure 4.5 on each --data path (its own
    /// corpus): word length, compression, seconds in 1,024 tokens, geodesic
    /// error, for the uniform, quantile and JPEG-like tile codecs.
    Tokenize {
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Write Figure 4.5 (error vs uniform bins) here as PNG.
        #[arg(long)]
        plot: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

pub fn run(cmd: EvalCmd) -> Result<()> {
    match cmd {
        EvalCmd::Footage(a) => super::footage::eval(a),
        EvalCmd::Query {
            data,
            labels,
            embedding,
            hop,
            k,
            same_sequence,
            queries,
            model,
            whiten,
            whiten_by,
            json,
        } => eval_query(
            data,
            labels,
            embedding,
            hop,
            k,
            (same_sequence, queries, whiten, whiten_by),
            model,
            json,
        ),
        EvalCmd::Tokenize { data, plot, json } => eval_tokenize(data, plot, json),
        EvalCmd::Generate {
            model,
            data,
            labels,
            per_label,
            seconds,
            lengths,
            sampling,
            exemplar,
            candidates,
            rank_every,
            root,
            feet,
            seed,
            json,
        } => super::eval_generate::run(
            &model,
            &data,
            &labels,
            (per_label, seconds, &lengths),
            (&sampling, seed),
            (&exemplar, &candidates, rank_every),
            (&root, &feet),
            json,
        ),
        EvalCmd::Keyframes {
            data,
            bpm,
            counts,
            json,
        } => eval_keyframes(data, bpm, counts, json),
        EvalCmd::Interpolate {
            data,
            pairs,
            seed,
            band,
            steps,
            lr,
            despike,
            json,
        } => eval_interpolate(data, pairs, seed, band, steps, lr, despike, json),
    }
}

fn eval_query(
    data: Vec<PathBuf>,
    labels: Vec<String>,
    embedding: Vec<String>,
    hop: usize,
    k: usize,
    (same, queries, whiten, whiten_by): (
        eval_q::SameSequence,
        eval_q::Queries,
        usize,
        eval_q::WhitenBy,
    ),
    model: Option<PathBuf>,
    json: bool,
) -> Result<()> {
    if data.is_empty() {
        bail!("--data: give at least one folder or file");
    }
    if whiten > 0 && queries != eval_q::Queries::HeldOut {
        bail!("--whiten: fitted on the training sequences, so it needs --queries held-out");
    }
    let embeddings: Vec<Embedding> = if embedding.is_empty() {
        Embedding::ALL.to_vec()
    } else {
        embedding
            .iter()
            .map(|e| {
                Embedding::parse(e).with_context(|| {
                    format!("--embedding: '{e}' is not stft, dct, pca, pose or lm")
                })
            })
            .collect::<Result<_>>()?
    };
    let lm = match (&model, embeddings.contains(&Embedding::Lm)) {
        (Some(dir), true) => {
            let m = choreo::lm::model::MotionModel::load(dir)
                .with_context(|| format!("--model {}", dir.display()))?;
            Some(choreo::lm::embed::LmEmbedder::new(&m).context("--model")?)
        }
        (None, true) => bail!("--embedding lm: give the frame model with --model DIR"),
        _ => None,
    };
    // Each --data folder is one corpus (the trainer's held-out split is per corpus).
    let (mut files, mut group) = (Vec::new(), Vec::new());
    for (i, d) in data.iter().enumerate() {
        let f = choreo::search::ingest::collect_files(std::slice::from_ref(d));
        group.extend(std::iter::repeat_n(i, f.len()));
        files.extend(f);
    }
    let t = std::time::Instant::now();
    let mut corpus = eval_q::build_corpus_with(&files, &group, hop, &embeddings, lm.as_ref());
    if whiten > 0 {
        if let eval_q::WhitenBy::Label(l) = &whiten_by {
            if !corpus.labels.iter().any(|x| x.contains_key(l)) {
                bail!("--whiten-by: no window has the label '{l}'");
            }
        }
        eval_q::whiten(&mut corpus, whiten, 1e-2, &whiten_by);
    }
    if corpus.sequence.is_empty() {
        bail!(
            "no windows: none of {} files gave a 128-frame window",
            files.len()
        );
    }
    let rows = eval_q::evaluate_queries(&corpus, &labels, k, same, queries);
    let majority = eval_q::majority_of(&corpus, &labels, queries);
    if json {
        let majority: Vec<_> = majority
            .iter()
            .map(|(l, a, n)| json!({"label": l, "accuracy": a, "windows": n}))
            .collect();
        println!(
            "{}",
            json!({"rows": rows, "majority": majority, "same_sequence": same, "queries": queries, "sequences": corpus.sequences, "windows": corpus.sequence.len(), "errors": corpus.errors, "seconds": t.elapsed().as_secs_f64()})
        );
    } else {
        println!(
            "{} sequences, {} windows (128 frames at 60 fps, hop {hop}), k = {k}, same-sequence neighbours {}, queries: {}",
            corpus.sequences,
            corpus.sequence.len(),
            match same {
                eval_q::SameSequence::Exclude => "excluded",
                eval_q::SameSequence::Allow => "allowed (the query window itself excluded)",
            },
            match queries {
                eval_q::Queries::All => "every window".to_string(),
                eval_q::Queries::HeldOut => format!(
                    "the {} windows of held-out sequences",
                    corpus.held_out.iter().filter(|h| **h).count()
                ),
            }
        );
        println!(
            "{:<6} {:<10} {:<12} {:>9} {:>13} {:>8}",
            "embed", "metric", "label", "accuracy", "entropy(ban)", "queries"
        );
        for r in &rows {
            println!(
                "{:<6} {:<10} {:<12} {:>8.1}% {:>13.3} {:>8}",
                r.embedding.name(),
                r.metric.name(),
                r.label,
                100.0 * r.accuracy,
                r.entropy_bans,
                r.queries
            );
        }
        for (l, a, n) in &majority {
            println!(
                "{:<6} {:<10} {:<12} {:>8.1}% {:>13} {:>8}",
                "majority",
                "",
                l,
                100.0 * a,
                "",
                n
            );
        }
        for e in &corpus.errors {
            println!("unreadable: {e}");
        }
    }
    Ok(())
}

fn eval_tokenize(data: Vec<PathBuf>, plot: Option<PathBuf>, json: bool) -> Result<()> {
    use choreo::eval::tokenize as et;
    use choreo::tokenize::eval::CodecReport;
    let t = std::time::Instant::now();
    let corpora = data
        .iter()
        .map(|d| et::eval_corpus(d).with_context(|| format!("--data {}", d.display())))
        .collect::<Result<Vec<_>>>()?;
    if let Some(p) = &plot {
        let png = choreo::plot::render_png(&et::figure_4_5(&corpora), 960, 600);
        std::fs::write(p, png).with_context(|| format!("--plot {}", p.display()))?;
    }
    if json {
        println!(
            "{}",
            json!({"corpora": corpora, "seconds": t.elapsed().as_secs_f64()})
        );
        return Ok(());
    }
    let table = |title: &str, rows: &[CodecReport]| {
        println!("\n{title}");
        println!(
            "{:<28} {:>9} {:>8} {:>11} {:>9} {:>10} {:>9} {:>9}",
            "codec",
            "avg word",
            "max word",
            "compression",
            "s in 1024",
            "mean err°",
            "p99 err°",
            "max err°"
        );
        for r in rows {
            println!(
                "{:<28} {:>9.1} {:>8} {:>11.1} {:>9.2} {:>10.4} {:>9.2} {:>9.2}",
                r.codec,
                r.avg_word_length,
                r.max_word_length,
                r.compression_factor,
                r.seconds_in_1024,
                r.mean_error_rad.to_degrees(),
                r.p99_error_rad.to_degrees(),
                r.max_error_rad.to_degrees()
            );
        }
    };
    for c in &corpora {
        println!(
            "== {} — {} files ({} unreadable), {} frames at 60 fps, {} channels",
            c.tables.corpus,
            c.files,
            c.errors.len(),
            c.tables.frame_codecs.first().map(|r| r.frames).unwrap_or(0),
            c.tables.channels
        );
        table("Frame codecs (SMPL-24, 60 fps)", &c.tables.frame_codecs);
        table(
            "Model layout (SMPL-13, 20 fps, angles only)",
            &c.model_layout,
        );
        table(
            "Table 4.1 (10% kept, 24 components, 360 quantile bins)",
            &c.tables.table_4_1,
        );
        table(
            "Table 4.2 (60-frame tiles, PCA, 360 quantile bins)",
            &c.tables.table_4_2,
        );
        table("Figure 4.5 (uniform bins)", &c.tables.figure_4_5);
    }
    println!("\n{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn eval_interpolate(
    data: Vec<PathBuf>,
    pairs: usize,
    seed: u64,
    band: (usize, usize),
    steps: usize,
    lr: f64,
    despike: bool,
    json: bool,
) -> Result<()> {
    use choreo::features::interpolate::InterpolateOptions;
    let files = choreo::search::ingest::collect_files(&data);
    let base = InterpolateOptions {
        objective: Embedding::Dct,
        band,
        steps,
        learning_rate: lr,
    };
    let t = std::time::Instant::now();
    let r = choreo::eval::interpolate::eval_interpolate(
        &files,
        pairs,
        seed,
        &Embedding::ALL,
        &base,
        despike,
    )?;
    if json {
        println!(
            "{}",
            json!({"rows": r.rows, "summary": r.summary, "files": r.files, "errors": r.errors, "seconds": t.elapsed().as_secs_f64()})
        );
        return Ok(());
    }
    println!(
        "{} pairs from {} files (seed {seed}), band {}:{}, {steps} Adam steps, lr {lr}, glitch repair {}",
        pairs.min(r.rows.len() / 3),
        r.files,
        band.0,
        band.1,
        if despike { "on" } else { "off" }
    );
    println!(
        "{:>4} {:<6} {:>7} {:>7} {:>7} {:>8} {:>9} {:>9} {:>9} {:>9}  input → target",
        "pair",
        "obj",
        "O→T",
        "I→O",
        "I→T",
        "between",
        "jerk in",
        "jerk swap",
        "jerk out",
        "med out"
    );
    let short = |s: &str| {
        std::path::Path::new(s)
            .file_stem()
            .map(|x| x.to_string_lossy().to_string())
            .unwrap_or_else(|| s.to_string())
    };
    for row in &r.rows {
        println!(
            "{:>4} {:<6} {:>7.3} {:>7.3} {:>7.3} {:>8} {:>9.0} {:>9.0} {:>9.0} {:>9.0}  {} → {}",
            row.pair,
            row.objective.name(),
            row.similarity.o_t,
            row.similarity.i_o,
            row.similarity.i_t,
            if row.between { "yes" } else { "no" },
            row.jitter.input,
            row.jitter.band_swap,
            row.jitter.output,
            row.jitter.median.output,
            short(&row.input),
            short(&row.target)
        );
    }
    println!("\nsummary (means over pairs; jerk in m/s³, 'band swap' = the input with its band replaced by the target's)");
    for s in &r.summary {
        println!(
            "{:<5} O→T {:.3}  I→O {:.3}  I→T {:.3}  between {}/{}  jerk input {:.0}, band swap {:.0}, output {:.0}; output/swap (medians) {:.2}",
            s.objective.name(),
            s.mean_o_t,
            s.mean_i_o,
            s.mean_i_t,
            s.between,
            s.pairs,
            s.mean_jerk_input,
            s.mean_jerk_band_swap,
            s.mean_jerk_output,
            s.median_jerk_ratio
        );
    }
    println!("{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn eval_keyframes(data: Vec<PathBuf>, bpm: f64, counts: Vec<usize>, json: bool) -> Result<()> {
    let files = choreo::search::ingest::collect_files(&data);
    let t = std::time::Instant::now();
    let r = choreo::eval::keyframes::eval_keyframes(&files, bpm, &counts)?;
    if json {
        println!(
            "{}",
            json!({"rows": r.rows, "clips": r.clips, "errors": r.errors, "seconds": t.elapsed().as_secs_f64()})
        );
        return Ok(());
    }
    for c in &r.clips {
        println!(
            "{}: {} BPM{}, {} frames a measure, {} measures",
            c.name,
            c.bpm,
            if c.tempo_known { "" } else { " (assumed)" },
            c.frames_per_measure,
            c.measures
        );
    }
    let f = |v: Option<f64>| v.map(|x| format!("{x:.2}")).unwrap_or_else(|| "—".into());
    for &n in &counts {
        println!("\n{n} keyframes per measure");
        println!(
            "{:<8} {:<11} {:>9} {:>10} {:>10}",
            "select", "in-between", "MSE cm²", "FID_k", "FID_g"
        );
        for row in r.rows.iter().filter(|x| x.keyframes_per_measure == n) {
            println!(
                "{:<8} {:<11} {:>9.3} {:>10} {:>10}",
                row.select.name(),
                row.inbetween,
                row.mse_cm2,
                f(row.fid_k),
                f(row.fid_g)
            );
        }
    }
    println!("\n{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}
