//! Style exemplars: short spans of real *training* motion, kept beside a
//! model, one or more per label value. A generation that asks for labels
//! and gives no seed motion is seeded with one of them (the span is context
//! only: it is not part of the output).
//!
//! Why: the frame model predicts the next frame almost entirely from the
//! frames before it, and its labels are worth a fraction of a bit per frame
//! (docs/RESULTS.md, "What the labels are worth"), so labels alone do not steer what
//! it generates. A few seconds of real motion of the asked-for style do:
//! the model continues them. `choreo eval generate --exemplar` measures the
//! two side by side.
//!
//! The file (`exemplars.json` in the model folder) is written by `choreo
//! exemplars`, which takes the spans only from the sequences the trainer
//! trained on (per corpus folder, the trainer's split: the first 10 % by a
//! hash of the name are held out), so held-out evaluations never see them.

use super::LmError;
use crate::motion::Labels;
use crate::tokenize::vocab::Vocabulary;
use base64::Engine;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The file name inside a model folder.
pub const FILE: &str = "exemplars.json";

/// One span: where it came from, its labels, and its frame tokens.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Exemplar {
    /// The source sequence's name (a file stem).
    pub source: String,
    /// Every label of the source sequence.
    pub labels: Labels,
    /// First frame of the span in the source (at the model's frame rate).
    pub start_frame: usize,
    pub frames: usize,
    /// Whole frames of tokens, little-endian u16, base64.
    pub tokens: String,
    /// The label values it was chosen for (files written before this
    /// field have none: every matching span is then in the pool).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub chosen_for: Vec<Chosen>,
}

impl Exemplar {
    /// The span's tokens.
    pub fn decode(&self) -> Result<Vec<u32>, String> {
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(self.tokens.as_bytes())
            .map_err(|e| format!("tokens: {e}"))?;
        if bytes.len() % 2 != 0 {
            return Err("tokens: an odd number of bytes".into());
        }
        Ok(bytes
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]) as u32)
            .collect())
    }

    fn encode(tokens: &[u32]) -> String {
        let bytes: Vec<u8> = tokens
            .iter()
            .flat_map(|&t| (t as u16).to_le_bytes())
            .collect();
        base64::engine::general_purpose::STANDARD.encode(bytes)
    }
}

/// A model's exemplars.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Exemplars {
    /// The model's frame rate and tokens per frame (checked at load).
    pub fps: f64,
    pub frame_len: usize,
    /// Seconds of each span the last `choreo exemplars` run wrote; a label
    /// value none of whose takes is that long has its longest takes whole
    /// instead, and spans kept from an earlier run for other kinds keep
    /// their own length (each item's `frames`).
    pub seconds: f64,
    pub items: Vec<Exemplar>,
    /// Decoded tokens, one per item.
    #[serde(skip)]
    decoded: Vec<Vec<u32>>,
}

impl Exemplars {
    /// The exemplars of a model folder, if it has any. A file that does not
    /// fit the model's vocabulary (frame rate, frame length, token range)
    /// is an error that names the field.
    pub fn load(dir: &Path, vocab: &Vocabulary) -> Result<Option<Exemplars>, LmError> {
        let path = if dir.is_dir() {
            dir.join(FILE)
        } else {
            dir.with_file_name(FILE)
        };
        let Some((mut ex, name)) = super::read_optional_json::<Exemplars>(&path, "exemplars")?
        else {
            return Ok(None);
        };
        if (ex.fps - vocab.fps).abs() > 1e-9 {
            return Err(LmError::invalid(
                &name,
                "fps",
                format!("{} but the model runs at {} fps", ex.fps, vocab.fps),
            ));
        }
        if ex.frame_len != vocab.frame_len() {
            return Err(LmError::invalid(
                &name,
                "frame_len",
                format!(
                    "{} but the model's frames are {} tokens",
                    ex.frame_len,
                    vocab.frame_len()
                ),
            ));
        }
        let mut decoded = Vec::with_capacity(ex.items.len());
        for (i, it) in ex.items.iter().enumerate() {
            let field = format!("items[{i}].tokens");
            let t = it
                .decode()
                .map_err(|e| LmError::invalid(&name, &field, e))?;
            if t.is_empty() || t.len() != it.frames * ex.frame_len {
                return Err(LmError::invalid(
                    &name,
                    &field,
                    format!(
                        "{} tokens for {} frames of {}",
                        t.len(),
                        it.frames,
                        ex.frame_len
                    ),
                ));
            }
            if let Some(bad) = t.iter().find(|&&x| x as usize >= vocab.size()) {
                return Err(LmError::invalid(
                    &name,
                    &field,
                    format!("token {bad} is outside the vocabulary ({})", vocab.size()),
                ));
            }
            decoded.push(t);
        }
        ex.decoded = decoded;
        Ok(Some(ex))
    }

    /// Writes `exemplars.json` into a model folder.
    pub fn save(&self, dir: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string(self).map_err(std::io::Error::other)?;
        std::fs::write(dir.join(FILE), text)
    }

    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Every span with its decoded tokens.
    pub fn spans(&self) -> impl Iterator<Item = (&Exemplar, &[u32])> {
        self.items
            .iter()
            .zip(self.decoded.iter().map(|t| t.as_slice()))
    }

    /// Keeps `old`'s spans for the label kinds this set was not built for,
    /// so that rewriting one kind's exemplars (`choreo exemplars --kind
    /// style`) leaves the other kinds' as they were: a span of `old` keeps
    /// its choices for other kinds and loses those for `kinds` (those are
    /// this set's now); a span left with no choice is dropped, as is one
    /// from a file without choices that carries a label of `kinds`.
    /// Returns how many spans were kept.
    pub fn keep_others(&mut self, old: Exemplars, kinds: &[String]) -> usize {
        let mut kept = 0;
        for (mut it, toks) in old.items.into_iter().zip(old.decoded) {
            if it.chosen_for.is_empty() {
                if kinds.iter().any(|k| it.labels.contains_key(k)) {
                    continue;
                }
            } else {
                it.chosen_for.retain(|c| !kinds.contains(&c.kind));
                if it.chosen_for.is_empty() {
                    continue;
                }
            }
            self.items.push(it);
            self.decoded.push(toks);
            kept += 1;
        }
        kept
    }

    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// The same spans (sources, first frames, lengths, labels, choices) as
    /// `old`, their tokens taken afresh from `sequences`, encoded with
    /// another vocabulary: for a model whose token layout differs from the
    /// one `old` was written for (say, heading-relative root velocity).
    /// `old` is read as written, not checked against any vocabulary. A
    /// span whose source is not among `sequences`, or is shorter than
    /// the span, is an error naming the item.
    pub fn reencoded(
        old: &Path,
        sequences: &[(String, Labels, Vec<u32>)],
        vocab: &Vocabulary,
    ) -> Result<Exemplars, LmError> {
        let Some((mut ex, name)) = super::read_optional_json::<Exemplars>(old, "exemplars")? else {
            return Err(LmError::invalid(
                &old.display().to_string(),
                "exemplars",
                "no such file",
            ));
        };
        let fl = vocab.frame_len();
        if (ex.fps - vocab.fps).abs() > 1e-9 {
            return Err(LmError::invalid(
                &name,
                "fps",
                format!("{} but the model runs at {} fps", ex.fps, vocab.fps),
            ));
        }
        // Sources are file names (see `build`); two corpora may hold the
        // same one, so the span's labels pick between them.
        let mut by_name: BTreeMap<String, Vec<(&Labels, &Vec<u32>)>> = BTreeMap::new();
        for (n, labels, t) in sequences {
            by_name.entry(file_name(n)).or_default().push((labels, t));
        }
        let mut decoded = Vec::with_capacity(ex.items.len());
        for (i, it) in ex.items.iter_mut().enumerate() {
            let field = format!("items[{i}].source");
            let found = by_name.get(&it.source).and_then(|c| {
                c.iter()
                    .find(|(l, _)| **l == it.labels)
                    .or(if c.len() == 1 { c.first() } else { None })
            });
            let t = found.map(|f| f.1).ok_or_else(|| {
                LmError::invalid(
                    &name,
                    &field,
                    format!("{:?} is not among the training sequences read", it.source),
                )
            })?;
            let (a, b) = (it.start_frame * fl, (it.start_frame + it.frames) * fl);
            if b > t.len() {
                return Err(LmError::invalid(
                    &name,
                    &field,
                    format!(
                        "{:?} has {} frames, the span ends at {}",
                        it.source,
                        t.len() / fl,
                        it.start_frame + it.frames
                    ),
                ));
            }
            it.tokens = Exemplar::encode(&t[a..b]);
            decoded.push(t[a..b].to_vec());
        }
        ex.frame_len = fl;
        ex.decoded = decoded;
        Ok(ex)
    }

    /// The exemplar for `labels`: among the spans whose source carries the
    /// most of the asked-for labels (at least one), those chosen for the
    /// most of them (a span of a happy walk chosen as a clear walk is not
    /// a clear example of happy), the one `seed` picks. None when `labels`
    /// is empty or no span shares any of them.
    pub fn pick(&self, labels: &Labels, seed: u64) -> Option<(&Exemplar, &[u32])> {
        if labels.is_empty() {
            return None;
        }
        let score = |e: &Exemplar| {
            let carries = labels
                .iter()
                .filter(|(k, v)| e.labels.get(*k) == Some(*v))
                .count();
            let chosen = e
                .chosen_for
                .iter()
                .filter(|c| labels.get(&c.kind) == Some(&c.value))
                .count();
            (carries, chosen)
        };
        let best = self.items.iter().map(score).max().unwrap_or((0, 0));
        if best.0 == 0 {
            return None;
        }
        let pool: Vec<usize> = (0..self.items.len())
            .filter(|&i| score(&self.items[i]) == best)
            .collect();
        let i = pool[(splitmix(seed) % pool.len() as u64) as usize];
        Some((&self.items[i], &self.decoded[i]))
    }

    /// Builds exemplars from training sequences (name, labels, frame
    /// tokens): for every label value of `kinds`, up to `per_label` spans
    /// of `seconds`, each from a different sequence. A span chosen for
    /// several values is stored once, and records which it was chosen for.
    ///
    /// Without a judge, the first `per_label` sequences of each value in
    /// the order of a hash of their names (so the choice does not depend on
    /// file order) give one span each, a third of the way in (the start of
    /// a take is often a still pose).
    ///
    /// With a judge (class probabilities of a span's frame tokens, per
    /// kind: a model's fitted heads), every long enough sequence offers
    /// [`CANDIDATES`] spans spread through it, and each value keeps the
    /// spans the judge finds likeliest to carry it: the clearest examples
    /// of the value, which is what a generation continues. A kind the
    /// judge does not classify falls back to the hash order.
    ///
    /// With `cover` a label kind (say `content`), the spans of each other
    /// kind's value are spread over that kind's values: the best span of
    /// each content first (contents in the order of their best span), then
    /// each content's second best, and so on, until `per_label`. A style's
    /// exemplars then walk, run, wave and raise their hands as its real
    /// takes do, instead of all being the few spans the judge likes best
    /// (which on Bandai were walks and waves only). Sequences without a
    /// `cover` label form one group; the `cover` kind's own values are
    /// chosen as without it.
    ///
    /// A value none of whose sequences is as long as a span gets its
    /// longest sequences whole instead (see [`MIN_SHORT_FRACTION`]).
    ///
    /// `choice` says how each value's spans spread over another kind
    /// (`cover`, above) and whether they are the openings of their takes
    /// (`from_start`: every take offers its first `seconds` only, judged or
    /// in hash order as above). A generation continues what its exemplar
    /// ends on: a span from inside a short take (Bandai's runs last 2.8 s)
    /// ends where the take stops, so the continuation stands; an opening
    /// ends where the take's content is still to come.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        sequences: &[(String, Labels, Vec<u32>)],
        vocab: &Vocabulary,
        kinds: &[String],
        seconds: f64,
        per_label: usize,
        judge: Option<&Judge<'_>>,
        choice: SpanChoice<'_>,
    ) -> Result<Exemplars, LmError> {
        let cover = choice.cover;
        let fl = vocab.frame_len();
        let len = ((seconds * vocab.fps).round() as usize).max(1);
        let mut order: Vec<usize> = (0..sequences.len())
            .filter(|&i| sequences[i].2.len() / fl >= len)
            .collect();
        order.sort_by_key(|&i| crate::data::split_hash(&sequences[i].0));
        // The (kind, value) pairs each sequence can stand for.
        let pairs: Vec<Vec<(String, String)>> = sequences
            .iter()
            .map(|(_, labels, _)| {
                kinds
                    .iter()
                    .filter_map(|k| {
                        let v = labels.get(k)?;
                        let known = vocab.labels.get(k).is_some_and(|s| s.contains(v));
                        known.then(|| (k.clone(), v.clone()))
                    })
                    .collect()
            })
            .collect();
        let candidates = |n: usize| -> Vec<usize> {
            if choice.from_start {
                return vec![0];
            }
            match judge {
                None => vec![(n - len) / 3],
                Some(_) => {
                    let mut s: Vec<usize> = (1..=CANDIDATES)
                        .map(|c| (n - len) * c / (CANDIDATES + 1))
                        .collect();
                    s.dedup();
                    s
                }
            }
        };
        // Every candidate span: (order rank, sequence, start, its judged
        // probability per (kind, value) of its own labels).
        type Cand = (usize, usize, usize, BTreeMap<(String, String), f64>);
        let work: Vec<(usize, usize, usize)> = order
            .iter()
            .enumerate()
            .filter(|(_, &i)| !pairs[i].is_empty())
            .flat_map(|(rank, &i)| {
                candidates(sequences[i].2.len() / fl)
                    .into_iter()
                    .map(move |st| (rank, i, st))
            })
            .collect();
        let judged: Vec<Result<Cand, LmError>> = {
            use rayon::prelude::*;
            work.par_iter()
                .map(|&(rank, i, st)| {
                    let mut p = BTreeMap::new();
                    if let Some(judge) = judge {
                        let table = judge(&sequences[i].2[st * fl..(st + len) * fl])?;
                        for (k, v) in &pairs[i] {
                            let prob = table
                                .iter()
                                .find(|(tk, _)| tk == k)
                                .and_then(|(_, vs)| vs.iter().find(|(tv, _)| tv == v))
                                .map(|(_, q)| *q);
                            if let Some(q) = prob {
                                p.insert((k.clone(), v.clone()), q);
                            }
                        }
                    }
                    Ok((rank, i, st, p))
                })
                .collect()
        };
        let judged: Vec<Cand> = judged.into_iter().collect::<Result<_, _>>()?;
        // Per (kind, value): candidates best first (judged probability,
        // then hash order), one span per sequence.
        let mut by_pair: BTreeMap<(String, String), Vec<&Cand>> = BTreeMap::new();
        for c in &judged {
            for pair in &pairs[c.1] {
                by_pair.entry(pair.clone()).or_default().push(c);
            }
        }
        // Keyed by (sequence, start, frames).
        let mut chosen: BTreeMap<(usize, usize, usize), Vec<Chosen>> = BTreeMap::new();
        // The values some span-long sequence carries.
        let covered: BTreeSet<(String, String)> = by_pair.keys().cloned().collect();
        for (pair, mut cands) in by_pair {
            cands.sort_by(|a, b| {
                let pa = a.3.get(&pair).copied().unwrap_or(0.0);
                let pb = b.3.get(&pair).copied().unwrap_or(0.0);
                pb.total_cmp(&pa).then(a.0.cmp(&b.0)).then(a.2.cmp(&b.2))
            });
            if let Some(by) = cover.filter(|by| *by != pair.0) {
                cands = spread_over(cands, |c| sequences[c.1].1.get(by));
            }
            let mut used = BTreeSet::new();
            for c in cands {
                if used.len() == per_label {
                    break;
                }
                if used.insert(c.1) {
                    chosen.entry((c.1, c.2, len)).or_default().push(Chosen {
                        kind: pair.0.clone(),
                        value: pair.1.clone(),
                        p: c.3.get(&pair).copied(),
                    });
                }
            }
        }
        // A value none of whose takes is as long as a span (Bandai's runs,
        // dashes and raised hands last 2–5 s) still gets exemplars: its
        // longest takes whole, if at least [`MIN_SHORT_FRACTION`] of a span,
        // so a request for it does not start from nothing.
        let min_short = ((len as f64 * MIN_SHORT_FRACTION).ceil() as usize).max(1);
        let mut short: BTreeMap<(String, String), Vec<usize>> = BTreeMap::new();
        for (i, ps) in pairs.iter().enumerate() {
            let n = sequences[i].2.len() / fl;
            if n >= len || n < min_short {
                continue;
            }
            for pair in ps.iter().filter(|p| !covered.contains(*p)) {
                short.entry(pair.clone()).or_default().push(i);
            }
        }
        for (pair, mut seqs) in short {
            // Longest first, then the hash order.
            seqs.sort_by_key(|&i| {
                (
                    std::cmp::Reverse(sequences[i].2.len()),
                    crate::data::split_hash(&sequences[i].0),
                )
            });
            for i in seqs.into_iter().take(per_label) {
                let n = sequences[i].2.len() / fl;
                chosen.entry((i, 0, n)).or_default().push(Chosen {
                    kind: pair.0.clone(),
                    value: pair.1.clone(),
                    p: None,
                });
            }
        }
        let mut items = Vec::new();
        let mut decoded = Vec::new();
        for ((i, st, frames), chosen_for) in chosen {
            let (name, labels, tokens) = &sequences[i];
            let span = tokens[st * fl..(st + frames) * fl].to_vec();
            items.push(Exemplar {
                source: file_name(name),
                labels: labels.clone(),
                start_frame: st,
                frames,
                tokens: Exemplar::encode(&span),
                chosen_for,
            });
            decoded.push(span);
        }
        Ok(Exemplars {
            fps: vocab.fps,
            frame_len: fl,
            seconds: len as f64 / vocab.fps,
            items,
            decoded,
        })
    }
}

/// How [`Exemplars::build`] places spans: spread over the values of the
/// kind `cover` names, and taken from the takes' openings (`from_start`)
/// instead of from inside them.
#[derive(Clone, Copy, Debug, Default)]
pub struct SpanChoice<'a> {
    pub cover: Option<&'a str>,
    pub from_start: bool,
}

/// The shortest whole take (a fraction of the span length) that may stand
/// in for a label value with no take as long as a span.
pub const MIN_SHORT_FRACTION: f64 = 0.3;

/// Candidate spans per sequence when a judge chooses.
pub const CANDIDATES: usize = 4;

/// Class probabilities per kind of a span's frame tokens (a model's
/// `classify`).
pub type Judge<'a> = dyn Fn(&[u32]) -> Result<crate::lm::model::ClassTable, LmError> + Sync + 'a;

/// A label value an exemplar was chosen for, and how likely the judge
/// found the value in it (absent when no judge chose).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chosen {
    pub kind: String,
    pub value: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p: Option<f64>,
}

/// A sequence's file name without its folders: the path it was read from
/// is this machine's, and answers repeat it.
fn file_name(name: &str) -> String {
    Path::new(name)
        .file_name()
        .map_or_else(|| name.to_string(), |f| f.to_string_lossy().into_owned())
}

/// A well-mixed index from a request's seed (consecutive seeds pick
/// unrelated exemplars).
fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// `items` (best first) reordered so that groups take turns: the best of
/// each group (groups in the order of their best), then each group's
/// second best, and so on. Within a group the order is kept.
fn spread_over<T, K: Ord>(items: Vec<T>, group: impl Fn(&T) -> K) -> Vec<T> {
    let mut groups: Vec<(K, Vec<T>)> = Vec::new();
    for it in items {
        let g = group(&it);
        match groups.iter_mut().find(|(k, _)| *k == g) {
            Some((_, v)) => v.push(it),
            None => groups.push((g, vec![it])),
        }
    }
    let mut queues: Vec<std::vec::IntoIter<T>> =
        groups.into_iter().map(|(_, v)| v.into_iter()).collect();
    let mut out = Vec::new();
    loop {
        let before = out.len();
        for q in &mut queues {
            out.extend(q.next());
        }
        if out.len() == before {
            return out;
        }
    }
}

#[cfg(test)]
mod tests;
