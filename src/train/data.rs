//! Training data: any mix of corpora read through the shared readers and
//! tokenized with the shared vocabulary; a split by sequence; mirror
//! augmentation; windows and batches.

use crate::lm::manifest::{sha256_hex, DataInfo};
use crate::lm::runtime::attention_bias;
use crate::lm::{ModelConfig, Objective};
use crate::motion::io::{self, ReadOptions};
use crate::motion::labels::from_name;
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use anyhow::{bail, Context, Result};
use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::Rng;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// One motion as tokens.
pub struct Sequence {
    pub name: String,
    pub corpus: String,
    pub labels: Labels,
    /// `frames × frame_len` tokens.
    pub tokens: Vec<u32>,
    /// The left/right mirror (training sequences only, when asked).
    pub mirrored: Option<Vec<u32>>,
}

impl Sequence {
    pub fn frames(&self, fl: usize) -> usize {
        self.tokens.len() / fl
    }
}

pub struct Corpus {
    pub train: Vec<Sequence>,
    pub val: Vec<Sequence>,
    pub info: DataInfo,
}

/// The folders of the named corpora under a data root.
pub fn corpus_dirs(root: &Path, names: &[String]) -> Result<Vec<(String, PathBuf)>> {
    let mut out = Vec::new();
    for n in names {
        let p = match n.as_str() {
            "aistpp" => root.join("aistpp/motions"),
            "aistpp-vrm" => root.join("aistpp-vrm/motions"),
            "bandai" => root.join("bandai"),
            "cmu" => root.join("cmu"),
            "amass" => root.join("amass"),
            other => PathBuf::from(other),
        };
        if !p.is_dir() {
            bail!("corpus {n}: folder {} does not exist (set --data or CHOREO_DATA to the folder holding aistpp/, bandai/, cmu/)", p.display());
        }
        out.push((n.clone(), p));
    }
    Ok(out)
}

fn licence(corpus: &str) -> &'static str {
    match corpus {
        "aistpp" | "aistpp-vrm" => "AIST++ annotations: Google LLC, CC BY 4.0",
        "bandai" => "Bandai Namco Research motion dataset: CC BY-NC 4.0",
        "cmu" => "CMU Graphics Lab motion capture: free for any use",
        "amass" => "AMASS: research licence of MPI (see amass.is.tue.mpg.de)",
        _ => "see the corpus's own licence",
    }
}

/// Reads every motion under the folders. Unreadable files are reported and
/// skipped; an empty result is an error.
pub fn read_motions(
    dirs: &[(String, PathBuf)],
) -> Result<(Vec<(String, crate::motion::Motion)>, DataInfo)> {
    let mut motions = Vec::new();
    let mut listing = Vec::new();
    let mut info = DataInfo::default();
    for (corpus, dir) in dirs {
        let files = crate::data::files_with_ext(dir, &["pkl", "npz", "bvh"]);
        for f in files {
            match io::read_path(&f, &ReadOptions::default()) {
                Ok(l) => {
                    let mut m = l.motion;
                    if m.labels.is_empty() {
                        m.labels = from_name(&m.name);
                    }
                    let size = std::fs::metadata(&f).map(|m| m.len()).unwrap_or(0);
                    listing.push(format!(
                        "{}\t{size}",
                        f.strip_prefix(dir).unwrap_or(&f).display()
                    ));
                    motions.push((corpus.clone(), m));
                }
                Err(e) => tracing::warn!("skipping {}: {e}", f.display()),
            }
        }
        info.corpora.push(corpus.clone());
        info.licences.push(format!("{corpus}: {}", licence(corpus)));
    }
    if motions.is_empty() {
        bail!(
            "empty corpus: no readable motion under {}",
            dirs.iter()
                .map(|d| d.1.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    listing.sort();
    info.files = listing.len();
    info.sha256 = sha256_hex(listing.join("\n").as_bytes());
    Ok((motions, info))
}

/// The vocabulary for a set of motions: labels of the given kinds.
pub fn vocabulary_for(
    motions: &[(String, crate::motion::Motion)],
    kinds: &[String],
    smpl24: bool,
) -> Vocabulary {
    let mut labels: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (_, m) in motions {
        for k in kinds {
            if let Some(v) = m.labels.get(k) {
                labels.entry(k.clone()).or_default().insert(v.clone());
            }
        }
    }
    let v = Vocabulary::new(labels);
    if smpl24 {
        v.with_smpl24()
    } else {
        v
    }
}

pub use crate::data::held_out_count;

/// Tokenizes and splits by sequence: within each corpus the sequences are
/// ordered by a hash of their name and the first `val_fraction` (at least
/// one) are held out. Mirrors are added to the training side only.
pub fn build(
    motions: Vec<(String, crate::motion::Motion)>,
    vocab: &Vocabulary,
    val_fraction: f64,
    mirror: bool,
    info: DataInfo,
) -> Result<Corpus> {
    build_chained(motions, vocab, val_fraction, mirror, info, &[])
}

/// [`build`], with the training takes of each corpus named in `chain` that
/// share every label but `take` (a Bandai content and style) played one
/// after another as one sequence ([`Motion::chain`], joined by
/// [`Motion::CHAIN_BRIDGE_S`]): a run cut short by the capture volume goes on into
/// the next take's, so a window can hold a longer pass than any one take.
/// Held-out takes stay single, so validation is unchanged.
///
/// [`Motion::chain`]: crate::motion::Motion::chain
/// [`Motion::CHAIN_BRIDGE_S`]: crate::motion::Motion::CHAIN_BRIDGE_S
pub fn build_chained(
    motions: Vec<(String, crate::motion::Motion)>,
    vocab: &Vocabulary,
    val_fraction: f64,
    mirror: bool,
    mut info: DataInfo,
    chain: &[String],
) -> Result<Corpus> {
    let mut by: BTreeMap<String, Vec<crate::motion::Motion>> = BTreeMap::new();
    for (c, m) in motions {
        by.entry(c).or_default().push(m);
    }
    let (mut train, mut val) = (Vec::new(), Vec::new());
    for (corpus, mut list) in by {
        list.sort_by_key(|m| crate::data::split_hash(&m.name));
        let mut n_val = held_out_count(list.len(), val_fraction);
        if chain.contains(&corpus) {
            let train_part = list.split_off(n_val.min(list.len()));
            n_val = list.len();
            list.extend(chain_alike(train_part));
        }
        for (i, m) in list.into_iter().enumerate() {
            let name = m.name.clone();
            // Retarget / resample once; the tokens and the mirror share it.
            let prepared = vocab
                .prepare(&m)
                .with_context(|| format!("tokenizing {name}"))?;
            let tokens = vocab
                .encode_motion(&prepared)
                .with_context(|| format!("tokenizing {name}"))?;
            if tokens.is_empty() {
                continue;
            }
            let held = i < n_val;
            let mirrored = if mirror && !held {
                // Mirrored on the vocabulary's skeleton (SMPL is symmetric; a BVH
                // rest pose often is not).
                match prepared.mirror().and_then(|mm| vocab.encode_motion(&mm)) {
                    Ok(t) => Some(t),
                    Err(e) => {
                        tracing::warn!("no mirror for {name}: {e}");
                        None
                    }
                }
            } else {
                None
            };
            let s = Sequence {
                name,
                corpus: corpus.clone(),
                labels: m.labels.clone(),
                tokens,
                mirrored,
            };
            if held {
                val.push(s)
            } else {
                train.push(s)
            }
        }
    }
    if train.is_empty() {
        bail!("empty corpus: no training sequence after the split");
    }
    info.chained_takes = chain.to_vec();
    info.train_sequences = train.len();
    info.val_sequences = val.len();
    info.train_tokens = train
        .iter()
        .map(|s| s.tokens.len() + s.mirrored.as_ref().map_or(0, |m| m.len()))
        .sum();
    Ok(Corpus { train, val, info })
}

/// Takes sharing every label but their take number, each group chained in
/// its (hash) order; a group that cannot chain (unlike skeletons) stays as
/// single takes.
fn chain_alike(takes: Vec<crate::motion::Motion>) -> Vec<crate::motion::Motion> {
    let alike = |m: &crate::motion::Motion| crate::motion::labels::but_take(&m.labels);
    let mut groups: Vec<Vec<crate::motion::Motion>> = Vec::new();
    for m in takes {
        match groups.iter_mut().find(|g| alike(&g[0]) == alike(&m)) {
            Some(g) => g.push(m),
            None => groups.push(vec![m]),
        }
    }
    let (mut out, n_groups) = (Vec::new(), groups.len());
    for g in groups {
        if g.len() < 2 {
            out.extend(g);
            continue;
        }
        let bridge = (crate::motion::Motion::CHAIN_BRIDGE_S * g[0].fps).round() as usize;
        match crate::motion::Motion::chain(&g, bridge) {
            Ok(mut c) => {
                c.name = format!("{} (+{} alike takes)", c.name, g.len() - 1);
                out.push(c);
            }
            Err(e) => {
                tracing::warn!("takes left unchained: {e}");
                out.extend(g);
            }
        }
    }
    tracing::info!(
        "chained takes: {} label groups, {} training sequences",
        n_groups,
        out.len()
    );
    out
}

/// One training or evaluation example before batching.
pub struct Example {
    pub tokens: Vec<u32>,
    /// Next-token (causal) or masked-token targets; `None` = no loss.
    pub targets: Vec<Option<u32>>,
    /// Class targets: (kind index, row, class index).
    pub classes: Vec<(usize, usize, usize)>,
    pub prefix_len: usize,
    pub n_frame_tokens: usize,
    pub n_class: usize,
}

/// How examples are cut.
#[derive(Clone, Debug)]
pub struct ExampleOptions {
    /// Probability of keeping each conditioning label (training).
    pub keep_label: f64,
    /// Probability that an example is a classification one (prefix `<bos>`
    /// only, class tokens at the end), when the model has class heads.
    pub classify: f64,
    pub mask_rate: f64,
}

/// An example from `frames` (whole frames of tokens) with these labels.
pub fn example(
    cfg: &ModelConfig,
    vocab: &Vocabulary,
    frames: &[u32],
    labels: &Labels,
    as_classifier: bool,
    opts: &ExampleOptions,
    rng: &mut StdRng,
) -> Example {
    let mut tokens = vec![vocab.bos()];
    if !as_classifier {
        for k in &cfg.cond_kinds {
            if let Some(v) = labels.get(k) {
                if rng.gen::<f64>() < opts.keep_label {
                    if let Ok(t) = vocab.label_token(k, v) {
                        tokens.push(t);
                    }
                }
            }
        }
    }
    let prefix_len = tokens.len();
    tokens.extend_from_slice(frames);
    let n_frame_tokens = frames.len();
    let mut classes = Vec::new();
    let mut n_class = 0;
    if as_classifier {
        for (ci, (k, values)) in cfg.classes.iter().enumerate() {
            let row = tokens.len();
            tokens.push(
                vocab
                    .class_token(k)
                    .expect("class kinds are in the vocabulary"),
            );
            n_class += 1;
            if let Some(v) = labels.get(k) {
                if let Some(idx) = values.iter().position(|x| x == v) {
                    classes.push((ci, row, idx));
                }
            }
        }
    }
    let n = tokens.len();
    let mut targets = vec![None; n];
    match cfg.objective {
        Objective::Causal => {
            // Predict every frame token from what precedes it.
            for i in prefix_len..prefix_len + n_frame_tokens {
                targets[i - 1] = Some(tokens[i]);
            }
        }
        Objective::Masked => {
            for i in prefix_len..prefix_len + n_frame_tokens {
                if rng.gen::<f64>() < opts.mask_rate {
                    targets[i] = Some(tokens[i]);
                    tokens[i] = vocab.mask();
                }
            }
        }
    }
    Example {
        tokens,
        targets,
        classes,
        prefix_len,
        n_frame_tokens,
        n_class,
    }
}

/// A batch as tensors.
pub struct Batch {
    pub tokens: Tensor,
    pub pos_a: Tensor,
    pub pos_b: Option<Tensor>,
    pub bias: Tensor,
    /// Flat `[B·T]` targets (0 where unused) and weights (1 where used).
    pub targets: Tensor,
    pub weights: Tensor,
    /// Per class kind: (flat rows, class indices).
    pub classes: Vec<Option<(Tensor, Tensor)>>,
    pub n_targets: usize,
    pub t: usize,
}

pub fn batch(
    cfg: &ModelConfig,
    vocab: &Vocabulary,
    exs: &[Example],
    dev: &Device,
) -> Result<Batch> {
    let b = exs.len();
    let t = exs.iter().map(|e| e.tokens.len()).max().unwrap_or(1);
    let (mut tok, mut pa, mut pb) = (
        vec![vocab.pad(); b * t],
        vec![0u32; b * t],
        vec![0u32; b * t],
    );
    let (mut tg, mut w) = (vec![0u32; b * t], vec![0f32; b * t]);
    // Masked models see every real token of their own example (pads hidden).
    let mut key_mask = vec![0f32; b * t];
    let mut cls: Vec<(Vec<u32>, Vec<u32>)> = vec![(Vec::new(), Vec::new()); cfg.classes.len()];
    let mut n_targets = 0;
    for (i, e) in exs.iter().enumerate() {
        let pos = cfg.positions(e.prefix_len, e.n_frame_tokens, e.n_class);
        for (j, &x) in e.tokens.iter().enumerate() {
            tok[i * t + j] = x;
            pa[i * t + j] = pos[j].a as u32;
            pb[i * t + j] = pos[j].b as u32;
            if let Some(y) = e.targets[j] {
                tg[i * t + j] = y;
                w[i * t + j] = 1.0;
                n_targets += 1;
            }
        }
        for k in e.tokens.len()..t {
            key_mask[i * t + k] = -1e9;
        }
        for &(ci, row, idx) in &e.classes {
            cls[ci].0.push((i * t + row) as u32);
            cls[ci].1.push(idx as u32);
        }
    }
    let classes = cls
        .into_iter()
        .map(|(rows, idx)| -> Result<Option<(Tensor, Tensor)>> {
            if rows.is_empty() {
                return Ok(None);
            }
            let n = rows.len();
            Ok(Some((
                Tensor::from_vec(rows, n, dev)?,
                Tensor::from_vec(idx, n, dev)?,
            )))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Batch {
        tokens: Tensor::from_vec(tok, (b, t), dev)?,
        pos_a: Tensor::from_vec(pa, (b, t), dev)?,
        pos_b: if cfg.table_b() > 0 {
            Some(Tensor::from_vec(pb, (b, t), dev)?)
        } else {
            None
        },
        // Causal: one mask shared by the batch, the runtime's own (pads sit
        // after every real token, so none is ever seen).
        bias: match cfg.objective {
            Objective::Causal => {
                Tensor::from_vec(attention_bias(Objective::Causal, 0, t), (1, 1, t, t), dev)?
            }
            Objective::Masked => Tensor::from_vec(key_mask, (b, 1, 1, t), dev)?,
        },
        targets: Tensor::from_vec(tg, b * t, dev)?,
        weights: Tensor::from_vec(w, b * t, dev)?,
        classes,
        n_targets,
        t,
    })
}

/// Draws a training window: a sequence (weighted by length), possibly its
/// mirror, and a start frame.
pub fn draw_window<'a>(
    train: &'a [Sequence],
    cum: &[usize],
    fl: usize,
    frames: usize,
    rng: &mut StdRng,
) -> (&'a [u32], &'a Labels) {
    let total = *cum.last().expect("non-empty");
    let r = rng.gen_range(0..total);
    let i = cum.partition_point(|&c| c <= r);
    let s = &train[i];
    let toks: &[u32] = match (&s.mirrored, rng.gen::<bool>()) {
        (Some(m), true) => m,
        _ => &s.tokens,
    };
    let n = toks.len() / fl;
    let w = frames.min(n);
    let start = rng.gen_range(0..=n - w);
    (&toks[start * fl..(start + w) * fl], &s.labels)
}

/// `(start, len)` cuts of `n` frames into windows of `w`, the last one
/// shorter when `w` does not divide `n`.
pub fn cuts(n: usize, w: usize) -> Vec<(usize, usize)> {
    let w = w.max(1);
    (0..n).step_by(w).map(|st| (st, w.min(n - st))).collect()
}

/// At most `max` of `items`, spread evenly (all of them when fewer): a
/// fixed subset keeps evaluation cheap and comparable.
pub fn spread<T: Copy>(items: Vec<T>, max: usize) -> Vec<T> {
    let n = items.len();
    if n <= max {
        return items;
    }
    (0..max).map(|i| items[i * n / max]).collect()
}

/// Every window of `w` frames of each sequence, the last one of each
/// shorter (whole frames of `fl` tokens), with the sequence's labels.
pub fn context_windows(seqs: &[Sequence], fl: usize, w: usize) -> Vec<(&[u32], &Labels)> {
    seqs.iter()
        .flat_map(|s| {
            cuts(s.frames(fl), w)
                .into_iter()
                .map(move |(st, len)| (&s.tokens[st * fl..(st + len) * fl], &s.labels))
        })
        .collect()
}

/// Fixed evaluation windows: every non-overlapping window of each sequence.
pub fn eval_windows(seqs: &[Sequence], fl: usize, frames: usize) -> Vec<(&[u32], &Labels)> {
    let mut out = Vec::new();
    for s in seqs {
        let n = s.frames(fl);
        if n == 0 {
            continue;
        }
        let w = frames.min(n);
        let mut st = 0;
        while st + w <= n {
            out.push((&s.tokens[st * fl..(st + w) * fl], &s.labels));
            st += w;
        }
    }
    out
}
