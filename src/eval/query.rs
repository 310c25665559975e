//! The thesis's query evaluation (000 §3.4, Table 3.2), made strict: every
//! window is a query; its neighbours from the same sequence are excluded;
//! k = 10; the predicted label is the majority of the neighbours' labels
//! (ties go to the label whose first vote is nearest); reported per label
//! kind: accuracy, and the mean entropy of the neighbours' labels in bans
//! (log base 10). Exact search, all three embeddings, both metrics. The
//! thesis's own protocol, where a window's neighbours may come from its own
//! sequence (only the window itself is left out), is `SameSequence::Allow`;
//! a majority-class row is the trivial baseline beside both.

use crate::features::{channels72, window, window_starts, Embedding, Extractor, Pca, StftParams};
use crate::index::{dot, push_top, Hit, Metric};
use crate::lm::embed::LmEmbedder;
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::Labels;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;

#[derive(Clone, Debug, Serialize)]
pub struct EvalRow {
    pub embedding: Embedding,
    pub metric: Metric,
    pub label: String,
    pub accuracy: f64,
    pub entropy_bans: f64,
    pub queries: usize,
}

/// The windows of a corpus with their sequence and labels, embedded.
pub struct Corpus {
    pub sequence: Vec<usize>,
    pub labels: Vec<Labels>,
    pub vectors: HashMap<Embedding, Vec<Vec<f32>>>,
    pub sequences: usize,
    pub errors: Vec<String>,
    /// Per window: its sequence is in the trainer's held-out split (per
    /// corpus, i.e. per `--data` folder, the first 10 % of sequences
    /// ordered by the SHA-256 of their name,
    /// [`crate::data::held_out_count`]): a model never trained on it.
    pub held_out: Vec<bool>,
}

/// Which windows are queries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Queries {
    /// Every window.
    All,
    /// Only windows of the trainer's held-out sequences (their neighbours
    /// may be any other sequence's): the fair test of an embedding learned
    /// from the same folders.
    HeldOut,
}

impl std::str::FromStr for Queries {
    type Err = String;
    fn from_str(s: &str) -> Result<Queries, String> {
        match s {
            "all" => Ok(Queries::All),
            "held-out" => Ok(Queries::HeldOut),
            other => Err(format!("{other:?}: expected all or held-out")),
        }
    }
}

pub fn build_corpus(files: &[PathBuf], hop: usize, embeddings: &[Embedding]) -> Corpus {
    build_corpus_with(files, &vec![0; files.len()], hop, embeddings, None)
}

/// [`build_corpus`], with the `lm` embedding when a frame model is given
/// (asked for without one, `lm` is left out and said in `errors`).
/// `corpus[i]` is file `i`'s corpus (the `--data` folder it came from),
/// for the held-out split.
pub fn build_corpus_with(
    files: &[PathBuf],
    corpus: &[usize],
    hop: usize,
    embeddings: &[Embedding],
    lm: Option<&LmEmbedder>,
) -> Corpus {
    let ex = Extractor::new(StftParams::default()).expect("default STFT");
    let mut windows: Vec<Vec<f32>> = Vec::new();
    let mut sequence = Vec::new();
    let mut labels = Vec::new();
    let mut errors = Vec::new();
    // Per corpus: (name hash, sequence) for the held-out split.
    let mut by_corpus: BTreeMap<usize, Vec<(String, usize)>> = BTreeMap::new();
    let mut seq = 0;
    for (f, &group) in files.iter().zip(corpus) {
        let loaded = match read_path(f, &ReadOptions::default()) {
            Ok(l) => l,
            Err(e) => {
                errors.push(e.to_string());
                continue;
            }
        };
        let ch = match channels72(&loaded.motion) {
            Ok(c) => c,
            Err(e) => {
                errors.push(e.to_string());
                continue;
            }
        };
        let starts = window_starts(ch.len(), hop);
        for &s in &starts {
            windows.push(window(&ch, s));
            sequence.push(seq);
            labels.push(loaded.motion.labels.clone());
        }
        let hash = crate::data::split_hash(&loaded.motion.name);
        by_corpus.entry(group).or_default().push((hash, seq));
        seq += 1;
    }
    let mut held_seq = vec![false; seq];
    for list in by_corpus.values_mut() {
        list.sort();
        for &(_, s) in list
            .iter()
            .take(crate::data::held_out_count(list.len(), 0.1))
        {
            held_seq[s] = true;
        }
    }
    let held_out = sequence.iter().map(|&s| held_seq[s]).collect();
    let mut vectors = HashMap::new();
    for &e in embeddings {
        let v: Vec<Vec<f32>> = match e {
            Embedding::Pca => match Pca::fit(windows.iter().map(|w| w.as_slice())) {
                Ok(p) => windows.iter().map(|w| p.project_window(w)).collect(),
                Err(_) => continue,
            },
            Embedding::Lm => {
                let Some(emb) = lm else {
                    errors.push("lm: no frame model given (--model DIR)".into());
                    continue;
                };
                match emb.many(&windows) {
                    Ok(v) => v,
                    Err(e) => {
                        errors.push(format!("lm: {e}"));
                        continue;
                    }
                }
            }
            _ => windows
                .iter()
                .map(|w| ex.embed(e, w, None).expect("stft/dct"))
                .collect(),
        };
        vectors.insert(e, v);
    }
    Corpus {
        sequence,
        labels,
        vectors,
        sequences: seq,
        errors,
        held_out,
    }
}

/// Widest embedding [`whiten`] maps (its within-sequence scatter is
/// `d × d`).
pub const MAX_WHITEN_DIM: usize = 2048;

/// What a whitening's classes are.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum WhitenBy {
    /// Each sequence is a class: no labels used.
    Sequence,
    /// The value of this label kind is the class (a supervised LDA, the
    /// fair comparator of an embedding fitted with labels); windows
    /// without the label stay out of the fit.
    Label(String),
}

impl std::str::FromStr for WhitenBy {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "" => Err("empty (want sequence or a label kind)".into()),
            "sequence" => Ok(WhitenBy::Sequence),
            l => Ok(WhitenBy::Label(l.to_string())),
        }
    }
}

/// Replaces every embedding's vectors by their whitening
/// ([`crate::features::whiten`]) with `k` directions, the classes being
/// sequences or a label's values (`by`), fitted on the windows of the
/// training (not held-out) sequences only; embeddings wider than
/// [`MAX_WHITEN_DIM`], or that cannot be fitted, are removed and said in
/// `errors`.
pub fn whiten(corpus: &mut Corpus, k: usize, shrink: f64, by: &WhitenBy) {
    let class: Vec<Option<usize>> = match by {
        WhitenBy::Sequence => corpus.sequence.iter().map(|&s| Some(s)).collect(),
        WhitenBy::Label(kind) => {
            let mut ids: HashMap<&str, usize> = HashMap::new();
            corpus
                .labels
                .iter()
                .map(|l| {
                    let n = ids.len();
                    l.get(kind).map(|v| *ids.entry(v.as_str()).or_insert(n))
                })
                .collect()
        }
    };
    let kinds: Vec<Embedding> = corpus.vectors.keys().copied().collect();
    for e in kinds {
        let v = &corpus.vectors[&e];
        let d = v.first().map_or(0, |x| x.len());
        if d > MAX_WHITEN_DIM {
            corpus.errors.push(format!(
                "{}: {d} values, too wide to whiten (at most {MAX_WHITEN_DIM}); left out",
                e.name()
            ));
            corpus.vectors.remove(&e);
            continue;
        }
        let (fit, seq): (Vec<&[f32]>, Vec<usize>) = v
            .iter()
            .zip(&class)
            .zip(&corpus.held_out)
            .filter_map(|((x, c), held)| (!*held).then_some((x.as_slice(), (*c)?)))
            .unzip();
        match crate::features::whiten::Whitening::fit(&fit, &seq, k, shrink) {
            Some(w) => {
                let mapped = v.iter().map(|x| w.apply(x)).collect();
                corpus.vectors.insert(e, mapped);
            }
            None => {
                corpus
                    .errors
                    .push(format!("{}: could not be whitened; left out", e.name()));
                corpus.vectors.remove(&e);
            }
        }
    }
}

/// Top-k neighbours of every vector under both metrics, excluding the same
/// sequence. Dot products are computed once and shared by the two metrics;
/// rows are split across threads.
/// Which neighbours a query may have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SameSequence {
    /// Strict: no window of the query's own sequence.
    Exclude,
    /// The thesis's protocol: any window but the query itself.
    Allow,
}

impl std::str::FromStr for SameSequence {
    type Err = String;
    fn from_str(s: &str) -> Result<SameSequence, String> {
        match s {
            "exclude" => Ok(SameSequence::Exclude),
            "allow" => Ok(SameSequence::Allow),
            other => Err(format!("{other:?}: expected exclude or allow")),
        }
    }
}

pub fn knn_both(
    vectors: &[Vec<f32>],
    sequence: &[usize],
    k: usize,
) -> (Vec<Vec<Hit>>, Vec<Vec<Hit>>) {
    knn_both_with(vectors, sequence, k, SameSequence::Exclude)
}

pub fn knn_both_with(
    vectors: &[Vec<f32>],
    sequence: &[usize],
    k: usize,
    same: SameSequence,
) -> (Vec<Vec<Hit>>, Vec<Vec<Hit>>) {
    knn_select(vectors, sequence, k, same, None)
}

/// [`knn_both_with`] for the windows `is_query` marks only (the others get
/// no neighbours; every window may be a neighbour).
pub fn knn_select(
    vectors: &[Vec<f32>],
    sequence: &[usize],
    k: usize,
    same: SameSequence,
    is_query: Option<&[bool]>,
) -> (Vec<Vec<Hit>>, Vec<Vec<Hit>>) {
    let n = vectors.len();
    let norms: Vec<f32> = vectors.iter().map(|v| dot(v, v).sqrt()).collect();
    let threads = std::thread::available_parallelism()
        .map(|t| t.get())
        .unwrap_or(1)
        .max(1);
    let chunk = n.div_ceil(threads).max(1);
    let mut cos = vec![Vec::new(); n];
    let mut euc = vec![Vec::new(); n];
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..n)
            .step_by(chunk)
            .map(|lo| {
                let hi = (lo + chunk).min(n);
                let norms = &norms;
                s.spawn(move || {
                    let mut out = Vec::with_capacity(hi - lo);
                    for i in lo..hi {
                        let (mut c, mut e) = (Vec::with_capacity(k + 1), Vec::with_capacity(k + 1));
                        if is_query.is_some_and(|q| !q[i]) {
                            out.push((c, e));
                            continue;
                        }
                        for j in 0..n {
                            let skip = match same {
                                SameSequence::Exclude => sequence[j] == sequence[i],
                                SameSequence::Allow => j == i,
                            };
                            if skip {
                                continue;
                            }
                            let d = dot(&vectors[i], &vectors[j]);
                            let denom = (norms[i] * norms[j]).max(1e-30);
                            push_top(
                                &mut c,
                                Hit {
                                    id: j,
                                    distance: 1.0 - d / denom,
                                },
                                k,
                            );
                            let sq = (norms[i] * norms[i] + norms[j] * norms[j] - 2.0 * d).max(0.0);
                            push_top(
                                &mut e,
                                Hit {
                                    id: j,
                                    distance: sq.sqrt(),
                                },
                                k,
                            );
                        }
                        out.push((c, e));
                    }
                    (lo, out)
                })
            })
            .collect();
        for h in handles {
            let (lo, out) = h.join().expect("kNN worker");
            for (i, (c, e)) in out.into_iter().enumerate() {
                cos[lo + i] = c;
                euc[lo + i] = e;
            }
        }
    });
    (cos, euc)
}

/// Majority-vote accuracy and mean entropy (bans) for one label kind.
pub fn score(neighbours: &[Vec<Hit>], labels: &[Labels], kind: &str) -> (f64, f64, usize) {
    let (mut correct, mut entropy, mut queries) = (0usize, 0.0f64, 0usize);
    for (i, hits) in neighbours.iter().enumerate() {
        let Some(truth) = labels[i].get(kind) else {
            continue;
        };
        let votes: Vec<&str> = hits
            .iter()
            .filter_map(|h| labels[h.id].get(kind).map(|s| s.as_str()))
            .collect();
        if votes.is_empty() {
            continue;
        }
        queries += 1;
        let mut counts: Vec<(&str, usize, usize)> = Vec::new(); // label, count, first rank
        for (rank, v) in votes.iter().enumerate() {
            match counts.iter_mut().find(|c| c.0 == *v) {
                Some(c) => c.1 += 1,
                None => counts.push((v, 1, rank)),
            }
        }
        let best = counts
            .iter()
            .max_by(|a, b| a.1.cmp(&b.1).then(b.2.cmp(&a.2)))
            .expect("votes");
        if best.0 == truth {
            correct += 1;
        }
        let n = votes.len() as f64;
        entropy += counts
            .iter()
            .map(|c| {
                let p = c.1 as f64 / n;
                -p * p.log10()
            })
            .sum::<f64>();
    }
    if queries == 0 {
        return (0.0, 0.0, 0);
    }
    (
        correct as f64 / queries as f64,
        entropy / queries as f64,
        queries,
    )
}

/// The majority-class baseline per label kind: the share of labelled
/// windows whose label is the most common one, over the same windows the
/// queries score.
pub fn majority(corpus: &Corpus, label_kinds: &[String]) -> Vec<(String, f64, usize)> {
    majority_of(corpus, label_kinds, Queries::All)
}

/// [`majority`] over the query windows of `queries`.
pub fn majority_of(
    corpus: &Corpus,
    label_kinds: &[String],
    queries: Queries,
) -> Vec<(String, f64, usize)> {
    label_kinds
        .iter()
        .map(|kind| {
            let mut counts: HashMap<&str, usize> = HashMap::new();
            for (i, l) in corpus.labels.iter().enumerate() {
                if queries == Queries::HeldOut && !corpus.held_out[i] {
                    continue;
                }
                if let Some(v) = l.get(kind) {
                    *counts.entry(v.as_str()).or_default() += 1;
                }
            }
            let n: usize = counts.values().sum();
            let top = counts.values().copied().max().unwrap_or(0);
            (kind.clone(), top as f64 / n.max(1) as f64, n)
        })
        .collect()
}

pub fn evaluate(corpus: &Corpus, label_kinds: &[String], k: usize) -> Vec<EvalRow> {
    evaluate_with(corpus, label_kinds, k, SameSequence::Exclude)
}

pub fn evaluate_with(
    corpus: &Corpus,
    label_kinds: &[String],
    k: usize,
    same: SameSequence,
) -> Vec<EvalRow> {
    evaluate_queries(corpus, label_kinds, k, same, Queries::All)
}

/// [`evaluate_with`] over the query windows of `queries`; every embedding
/// the corpus holds, the spectral ones first.
pub fn evaluate_queries(
    corpus: &Corpus,
    label_kinds: &[String],
    k: usize,
    same: SameSequence,
    queries: Queries,
) -> Vec<EvalRow> {
    let mut rows = Vec::new();
    let mask = (queries == Queries::HeldOut).then_some(corpus.held_out.as_slice());
    for e in Embedding::ALL
        .into_iter()
        .chain([Embedding::Pose, Embedding::Lm])
    {
        let Some(v) = corpus.vectors.get(&e) else {
            continue;
        };
        let (cos, euc) = knn_select(v, &corpus.sequence, k, same, mask);
        for (metric, nb) in [(Metric::Cosine, &cos), (Metric::Euclidean, &euc)] {
            for kind in label_kinds {
                let (accuracy, entropy_bans, queries) = score(nb, &corpus.labels, kind);
                rows.push(EvalRow {
                    embedding: e,
                    metric,
                    label: kind.clone(),
                    accuracy,
                    entropy_bans,
                    queries,
                });
            }
        }
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(v: &str) -> Labels {
        [("style".to_string(), v.to_string())].into_iter().collect()
    }

    #[test]
    fn majority_and_entropy_by_hand() {
        // Query 0 (label a) has neighbours a, a, b: right, entropy of (2/3, 1/3).
        let hits = vec![vec![
            Hit {
                id: 1,
                distance: 0.1,
            },
            Hit {
                id: 2,
                distance: 0.2,
            },
            Hit {
                id: 3,
                distance: 0.3,
            },
        ]];
        let l = vec![labels("a"), labels("a"), labels("a"), labels("b")];
        let (acc, ent, q) = score(&hits, &l, "style");
        assert_eq!((acc, q), (1.0, 1));
        let want =
            -(2.0f64 / 3.0) * (2.0f64 / 3.0).log10() - (1.0f64 / 3.0) * (1.0f64 / 3.0).log10();
        assert!((ent - want).abs() < 1e-12);
    }

    #[test]
    fn same_sequence_is_excluded() {
        let v = vec![vec![1.0, 0.0], vec![1.0, 0.01], vec![0.0, 1.0]];
        let (cos, _) = knn_both(&v, &[0, 0, 1], 2);
        assert_eq!(cos[0].len(), 1);
        assert_eq!(cos[0][0].id, 2);
        // The thesis's protocol keeps the sibling window, never the query.
        let (cos, _) = knn_both_with(&v, &[0, 0, 1], 2, SameSequence::Allow);
        assert_eq!(cos[0].iter().map(|h| h.id).collect::<Vec<_>>(), vec![1, 2]);
    }

    #[test]
    fn majority_counts_labelled_windows() {
        let corpus = Corpus {
            sequence: vec![0, 0, 1, 2],
            labels: vec![labels("a"), labels("a"), labels("b"), Labels::new()],
            vectors: HashMap::new(),
            sequences: 3,
            errors: Vec::new(),
            held_out: vec![false, false, true, true],
        };
        let m = majority(&corpus, &["style".to_string()]);
        assert_eq!(m[0].2, 3);
        assert!((m[0].1 - 2.0 / 3.0).abs() < 1e-12);
        // Over the held-out queries only: the one labelled window there.
        let h = majority_of(&corpus, &["style".to_string()], Queries::HeldOut);
        assert_eq!((h[0].1, h[0].2), (1.0, 1));
    }

    #[test]
    fn only_marked_windows_are_queries_but_all_are_neighbours() {
        let v = vec![vec![1.0, 0.0], vec![1.0, 0.01], vec![0.0, 1.0]];
        let (cos, euc) = knn_select(
            &v,
            &[0, 1, 2],
            2,
            SameSequence::Exclude,
            Some(&[false, true, false]),
        );
        assert!(cos[0].is_empty() && cos[2].is_empty() && euc[0].is_empty());
        // The held-out query's nearest neighbour is a non-query window.
        assert_eq!(cos[1][0].id, 0);
    }
}
