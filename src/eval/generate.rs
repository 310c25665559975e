//! `choreo eval generate`: generated motion measured against held-out real
//! clips of the same label (issue 15). For each label value with held-out
//! clips, the model generates `per_label` clips of `seconds` conditioned on
//! it; every sampling setting gives one row:
//!
//! - FID_k / FID_g (the project's kinetic and geometric features, SMPL-24
//!   positions) of generated vs held-out segments, beside the same figure
//!   for real training segments vs held-out ones (the real-vs-real yardstick);
//! - acceleration, jerk and foot-skating ratios to the held-out clips
//!   (acceleration and jerk on root-relative joint positions; skating on
//!   the ankles' ground speed while within 3 cm of the clip's lowest ankle);
//! - the frozen fraction: 1 s windows whose mean root-relative joint speed
//!   is under a tenth of the held-out clips' mean, beside the same share
//!   of the held-out clips' own windows (real dancers hold still too);
//! - diversity: mean pairwise distance of standardised kinetic features,
//!   generated and real;
//! - conditioning accuracy: an LDA fitted on real *training* windows only
//!   (2 s windows of token statistics) names each generated window's label;
//!   its accuracy on held-out real windows is the yardstick.
//!
//! Held-out clips are chosen as the trainer chooses them: sorted by a hash
//! of their name, the first 10 % (at least one).
//! Real and generated clips both go through the tokenizer and back, so the
//! quantisation is the same on both sides.

use crate::features::lda::{window_features, Lda};
use crate::keyframes::metrics::{
    feature_gaps, fid, fid_range, fid_same_size, first_axis, geometric_features, kinetic_features,
    same_size_by,
};
use crate::lm::model::MotionModel;
use crate::lm::Sampling;
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::labels::from_name;
use crate::motion::rotation::Vec3;
use crate::motion::skeleton::SMPL13_FROM_24;
use crate::motion::{Labels, Motion, Skeleton};
use crate::tokenize::vocab::Vocabulary;
use std::collections::BTreeMap;
use std::path::Path;

mod chained;
mod clip;
mod row;
use clip::{clip_stats, diversity, ClipStats};
use row::{kinetic_name, GAPS_SHOWN};
pub use row::{FeatureGap, GenRow, KineticAxis, LabelAcc};

/// How far past the real frames' floor band a lowest joint may go before
/// the frame counts as sunk or floating (metres): the real band's lower
/// edge is a flat foot on the floor to the millimetre, and a pointed toe
/// a centimetre or two lower is not a body in the floor.
pub const FLOOR_SLACK: f64 = 0.025;

#[derive(Clone)]
pub struct GenOptions {
    pub label_kind: String,
    pub per_label: usize,
    pub seconds: f64,
    /// Clip k of a label lasts as long as the label's k-th held-out
    /// segment (cycled) instead of `seconds`.
    pub held_out_lengths: bool,
    pub samplings: Vec<Sampling>,
    pub val_fraction: f64,
    /// The model's style exemplars, and whether each row seeds with one
    /// (`false`: from nothing, `true`: an exemplar of the label): every
    /// sampling runs once per entry.
    pub exemplars: Option<crate::lm::exemplars::Exemplars>,
    pub exemplar_modes: Vec<bool>,
    /// Best of N ([`crate::lm::best_of`]): each row runs once per entry.
    pub candidates: Vec<u32>,
    /// With more than one candidate: rank continuations of this many
    /// frames as the clip is made ([`crate::lm::steer`]); 0 ranks whole clips.
    pub rank_every: usize,
    /// How each generated clip's root travels, one row per entry: `false`
    /// as its tokens carry it, `true` rebuilt from its feet
    /// ([`crate::motion::contact`]) and set on the floor. Where the real
    /// clips have no root trajectory the path is dropped either way, and
    /// the rows differ in the height alone.
    pub root_from_feet: Vec<bool>,
    /// How each generated clip's legs are taken, one row per entry (times
    /// the root's): `false` as the model made them, `true` with the feet
    /// pinned where they touch the floor ([`crate::motion::foot_pin`]).
    pub pin_feet: Vec<bool>,
}

/// A sampling setting as a row names it.
pub fn sampling_name(s: &Sampling) -> String {
    if s.temperature == 0.0 {
        return "greedy".into();
    }
    // Each optional setting, named only when it is not its "off" value.
    let extras = [
        ("guidance", s.guidance, 1.0),
        ("keep_near", s.keep_near as f64, 0.0),
        ("max_jump", s.max_jump as f64, 0.0),
        ("posture", s.posture, 0.0),
        ("context", s.context as f64, 0.0),
        ("draws", s.draws as f64, 1.0),
        ("pace", s.pace, 0.0),
        ("jerk", s.jerk, 0.0),
        ("ease", s.ease, 0.0),
        ("matching", s.matching, 0.0),
        ("travel", s.travel, 1.0),
        ("skate", s.skate, 0.0),
    ];
    let mut name = format!("t={} top_k={} top_p={}", s.temperature, s.top_k, s.top_p);
    for (field, value, off) in extras {
        if value != off {
            name.push_str(&format!(" {field}={value}"));
        }
    }
    name
}

/// A real clip of the folder: its name, labels, tokens and the motion they
/// encode (the vocabulary's skeleton and frame rate; its own name and
/// labels as the vocabulary's preparation left them: read the clip's).
pub struct RealClip {
    pub name: String,
    pub labels: Labels,
    pub tokens: Vec<u32>,
    pub motion: Motion,
}

/// Every readable motion under `data` (labels from the file name when the
/// file has none), tokenized, and split as the trainer splits a corpus:
/// ordered by a hash of the name, the first `val_fraction` (at least one)
/// held out. Returns (held out, training).
pub fn read_split(
    vocab: &Vocabulary,
    data: &Path,
    val_fraction: f64,
    say: &mut dyn FnMut(String),
) -> anyhow::Result<(Vec<RealClip>, Vec<RealClip>)> {
    let mut clips: Vec<(String, RealClip)> = Vec::new();
    for f in crate::data::files_with_ext(data, &["pkl", "npz", "bvh"]) {
        match read_path(&f, &ReadOptions::default()) {
            Ok(l) => {
                let mut m = l.motion;
                if m.labels.is_empty() {
                    m.labels = from_name(&m.name);
                }
                let prepared = vocab
                    .prepare(&m)
                    .and_then(|p| vocab.encode_motion(&p).map(|t| (p, t)));
                match prepared {
                    Ok((p, t)) if !t.is_empty() => clips.push((
                        crate::data::split_hash(&m.name),
                        RealClip {
                            name: m.name,
                            labels: m.labels,
                            tokens: t,
                            motion: p,
                        },
                    )),
                    Ok(_) => {}
                    Err(e) => say(format!("skipping {}: {e}", f.display())),
                }
            }
            Err(e) => say(format!("skipping {}: {e}", f.display())),
        }
    }
    if clips.is_empty() {
        anyhow::bail!("data: no readable motion under {}", data.display());
    }
    clips.sort_by(|a, b| a.0.cmp(&b.0));
    let n_val = crate::data::held_out_count(clips.len(), val_fraction);
    let (val, train): (Vec<_>, Vec<_>) =
        clips.into_iter().enumerate().partition(|(i, _)| *i < n_val);
    Ok((
        val.into_iter().map(|(_, c)| c.1).collect(),
        train.into_iter().map(|(_, c)| c.1).collect(),
    ))
}

fn mean(x: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = x.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    s / n.max(1) as f64
}

/// Runs the evaluation; `say` receives progress lines (skipped labels,
/// unreadable files).
pub fn eval_generate(
    model: &MotionModel,
    data: &Path,
    o: &GenOptions,
    say: &mut dyn FnMut(String),
) -> anyhow::Result<Vec<GenRow>> {
    let vocab = model.vocabulary().clone();
    let fl = vocab.frame_len();
    let kind = &o.label_kind;
    if !model.cond_kinds().contains(kind) {
        anyhow::bail!(
            "labels: the model is not conditioned on {kind:?} (it takes: {})",
            model.cond_kinds().join(", ")
        );
    }
    let known = vocab.labels.get(kind).cloned().unwrap_or_default();
    let (val, train) = read_split(&vocab, data, o.val_fraction, say)?;
    let seg = (o.seconds * vocab.fps).round().max(4.0) as usize;
    let segments = |cs: &[RealClip]| -> Vec<(String, Vec<u32>)> {
        let mut out = Vec::new();
        for c in cs {
            let Some(v) = c.labels.get(kind) else {
                continue;
            };
            let n = c.tokens.len() / fl;
            if n < seg {
                out.push((v.clone(), c.tokens.clone()));
                continue;
            }
            let mut st = 0;
            while st + seg <= n {
                out.push((v.clone(), c.tokens[st * fl..(st + seg) * fl].to_vec()));
                st += seg;
            }
        }
        out
    };
    let val_segs = segments(&val);
    let train_segs = segments(&train);
    // A corpus with no root trajectory (AIST++-VRM: every real frame's
    // ground velocity is the zero bin) cannot judge generated travel.
    let still = vocab.encode_root_velocity(0.0);
    let in_place = val_segs.iter().chain(&train_segs).all(|(_, t)| {
        t.chunks_exact(fl)
            .all(|f| vocab.root_velocity_tokens(f) == (still, still))
    });
    if in_place {
        say("the real clips have no root trajectory: both sides are measured with the root held in place".into());
    }
    // The labels to generate: known to the model, present in held-out clips.
    let mut values: Vec<String> = val_segs
        .iter()
        .map(|s| s.0.clone())
        .filter(|v| known.contains(v))
        .collect();
    values.sort();
    values.dedup();
    for v in val_segs.iter().map(|s| &s.0) {
        if !known.contains(v) {
            say(format!("label {kind}={v}: unknown to the model, skipped"));
        }
    }
    let all_values: Vec<String> = known.iter().cloned().collect();
    if values.is_empty() {
        anyhow::bail!("data: no held-out clip carries a {kind} the model knows");
    }
    let stats = |segs: &[(String, Vec<u32>)]| -> anyhow::Result<Vec<(String, ClipStats)>> {
        segs.iter()
            .filter(|s| values.contains(&s.0))
            .map(|(v, t)| {
                clip_stats(&vocab, t, in_place, (false, false))
                    .map(|s| (v.clone(), s))
                    .map_err(|e| anyhow::anyhow!("{e}"))
            })
            .collect()
    };
    let real = stats(&val_segs)?;
    let real_train = stats(&train_segs)?;
    // The conditioning judge: LDA on real training windows only.
    let (mut x, mut y) = (Vec::new(), Vec::new());
    for (v, s) in &real_train {
        if let Some(c) = all_values.iter().position(|a| a == v) {
            for w in &s.lda_windows {
                x.push(w.clone());
                y.push(c);
            }
        }
    }
    let judge = Lda::fit(&x, &y, all_values.len(), 0.1);
    // The judge's verdicts, read once per window, tallied as (hits,
    // windows) on each clip's k-th window, k = 0, 1, … (the accuracy
    // overall, and whether the label holds as the clip goes on) and per
    // label value.
    type Tally = (Vec<(usize, usize)>, BTreeMap<String, (usize, usize)>);
    let judged = |rows: &[(String, &ClipStats)]| -> Tally {
        let (mut by_window, mut by_label) = (Vec::new(), BTreeMap::new());
        let Some(j) = &judge else {
            return (by_window, by_label);
        };
        for (v, s) in rows {
            let e: &mut (usize, usize) = by_label.entry(v.clone()).or_default();
            for (k, w) in s.lda_windows.iter().enumerate() {
                let hit = (all_values.get(j.predict(w)) == Some(v)) as usize;
                if by_window.len() <= k {
                    by_window.push((0, 0));
                }
                by_window[k].0 += hit;
                by_window[k].1 += 1;
                e.0 += hit;
                e.1 += 1;
            }
        }
        (by_window, by_label)
    };
    let share = |(hit, n): (usize, usize)| hit as f64 / n.max(1) as f64;
    let overall =
        |by: &[(usize, usize)]| share(by.iter().fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1)));
    let real_refs: Vec<(String, &ClipStats)> = real.iter().map(|(v, s)| (v.clone(), s)).collect();
    let (real_by_window, real_by_label) = judged(&real_refs);
    let cond_acc_real = overall(&real_by_window);
    let rk: Vec<Vec<f64>> = real.iter().map(|r| r.1.kinetic.clone()).collect();
    let rg: Vec<Vec<f64>> = real.iter().map(|r| r.1.geometric.clone()).collect();
    let tk: Vec<Vec<f64>> = real_train.iter().map(|r| r.1.kinetic.clone()).collect();
    let tg: Vec<Vec<f64>> = real_train.iter().map(|r| r.1.geometric.clone()).collect();
    let real_speed = mean(real.iter().flat_map(|r| r.1.window_speed.iter().copied()));
    // The share of 1 s windows under a tenth of the held-out clips' mean
    // speed: generated clips' (`frozen`), and the held-out clips' own
    // (`frozen_real`, how often real dancers hold still).
    let still = |w: &mut dyn Iterator<Item = f64>| -> f64 {
        let (n, k) = w.fold((0usize, 0usize), |(n, k), s| {
            (n + 1, k + (s < 0.1 * real_speed) as usize)
        });
        k as f64 / n.max(1) as f64
    };
    let frozen_real = still(&mut real.iter().flat_map(|r| r.1.window_speed.iter().copied()));
    let real_accel = mean(real.iter().map(|r| r.1.accel));
    let real_jerk = mean(real.iter().map(|r| r.1.jerk));
    let real_skate = mean(real.iter().map(|r| r.1.skate));
    // The real training frames' bands: tilt up to its 99th percentile,
    // the lowest joint between its 0.5th and 99.5th.
    let sorted = |f: fn(&ClipStats) -> &Vec<f64>| -> Vec<f64> {
        let mut v: Vec<f64> = real_train.iter().flat_map(|r| f(&r.1).clone()).collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let (train_tilt, train_low) = (sorted(|s| &s.tilt), sorted(|s| &s.lowest));
    let tilt_max = super::percentile(&train_tilt, 0.99);
    let (low_lo, low_hi) = (
        super::percentile(&train_low, 0.005) - FLOOR_SLACK,
        super::percentile(&train_low, 0.995) + FLOOR_SLACK,
    );
    let out_share = |clips: &[(String, &ClipStats)]| -> (f64, f64) {
        let share =
            |xs: Vec<bool>| xs.iter().filter(|&&b| b).count() as f64 / xs.len().max(1) as f64;
        (
            share(
                clips
                    .iter()
                    .flat_map(|r| r.1.tilt.iter().map(|&t| t > tilt_max))
                    .collect(),
            ),
            share(
                clips
                    .iter()
                    .flat_map(|r| r.1.lowest.iter().map(|&y| y < low_lo || y > low_hi))
                    .collect(),
            ),
        )
    };
    let (tilt_out_real, floor_out_real) = out_share(&real_refs);
    let mut rows = Vec::new();
    if o.exemplar_modes.contains(&true) && o.exemplars.is_none() {
        anyhow::bail!(
            "exemplar: the model folder has no exemplars.json (make one with choreo exemplars)"
        );
    }
    // The real yardsticks, the same for every row: every row generates
    // per_label clips of each value.
    let (fid_k_real, fid_g_real) = (fid(&rk, &tk), fid(&rg, &tg));
    let n_gen = values.len() * o.per_label;
    let (fid_k_real_same_n, fid_g_real_same_n) = (
        fid_same_size(&rk, &tk, n_gen),
        fid_same_size(&rg, &tg, n_gen),
    );
    let fid_k_real_same_n_without = same_size_by(&rk, &tk, n_gen, |r, p| {
        first_axis(r, p).map(|a| a.fid_without)
    });
    // Real training takes of each value played on to the generated length
    // (not with held-out lengths: those clips are as long as the takes).
    let real_chained = if o.held_out_lengths {
        None
    } else {
        let clips = chained::chained_clips(&vocab, &train, (kind, &values), o.per_label, seg, say);
        let stats = stats(&clips)?;
        (!stats.is_empty()).then(|| chained::measure(&stats, &real))
    };
    let runs: Vec<(&Sampling, bool, u32)> = o
        .samplings
        .iter()
        .flat_map(|s| o.exemplar_modes.iter().map(move |&e| (s, e)))
        .flat_map(|(s, e)| o.candidates.iter().map(move |&n| (s, e, n)))
        .collect();
    // Where the real clips stay in place the feet's ground path is dropped
    // with the rest, but the height they set (on the floor, not floating)
    // is still measured.
    let root_modes = o.root_from_feet.clone();
    // With held-out lengths: each value's held-out segments' frame counts,
    // in order (every generated value has at least one).
    let mut held_out_frames: BTreeMap<&String, Vec<usize>> = BTreeMap::new();
    if o.held_out_lengths {
        for (v, t) in &val_segs {
            held_out_frames.entry(v).or_default().push(t.len() / fl);
        }
    }
    for (sampling, with_exemplar, candidates) in runs {
        let t0 = std::time::Instant::now();
        let mut made: Vec<(String, Vec<u32>)> = Vec::new();
        for v in &values {
            let mut labels = Labels::new();
            labels.insert(kind.clone(), v.clone());
            for i in 0..o.per_label {
                let seg = held_out_frames.get(v).map_or(seg, |ls| ls[i % ls.len()]);
                let mut s = sampling.clone();
                s.seed = sampling.seed.wrapping_add(i as u64);
                let free = vec![None; fl];
                // The exemplar a sampling seed picks, as the API does.
                let context = |seed: u64| -> &[u32] {
                    match (&o.exemplars, with_exemplar) {
                        (Some(ex), true) => ex.pick(&labels, seed).map_or(&[][..], |p| p.1),
                        _ => &[],
                    }
                };
                let toks = if candidates > 1 && o.rank_every > 0 {
                    let mut g = model.steered(
                        &labels,
                        context(s.seed),
                        s.clone(),
                        (candidates, o.rank_every),
                    )?;
                    let mut toks = Vec::with_capacity(seg * fl);
                    for _ in 0..seg {
                        toks.extend(g.next_frame(&|_| free.clone())?);
                    }
                    toks
                } else {
                    crate::lm::best_of::best_of(model, &labels, candidates, |j| {
                        let mut sj = s.clone();
                        sj.seed = crate::lm::best_of::candidate_seed(s.seed, j);
                        // Each candidate picks its exemplar with its own seed.
                        let mut g = model.generator(&labels, context(sj.seed), sj)?;
                        let mut toks = Vec::with_capacity(seg * fl);
                        for _ in 0..seg {
                            toks.extend(g.next_frame(&free)?);
                        }
                        Ok(toks)
                    })?
                    .tokens
                };
                made.push((v.clone(), toks));
            }
        }
        let secs = t0.elapsed().as_secs_f64() / made.len().max(1) as f64;
        let modes: Vec<(bool, bool)> = root_modes
            .iter()
            .flat_map(|&r| o.pin_feet.iter().map(move |&p| (r, p)))
            .collect();
        for &(feet, pin) in &modes {
            let gen: Vec<(String, ClipStats)> = made
                .iter()
                .map(|(v, t)| {
                    clip_stats(&vocab, t, in_place, (feet, pin))
                        .map(|s| (v.clone(), s))
                        .map_err(|e| anyhow::anyhow!("{e}"))
                })
                .collect::<anyhow::Result<_>>()?;
            let gk: Vec<Vec<f64>> = gen.iter().map(|r| r.1.kinetic.clone()).collect();
            let gg: Vec<Vec<f64>> = gen.iter().map(|r| r.1.geometric.clone()).collect();
            let frozen = still(&mut gen.iter().flat_map(|r| r.1.window_speed.iter().copied()));
            let refs: Vec<(String, &ClipStats)> = gen.iter().map(|(v, s)| (v.clone(), s)).collect();
            let (by_window, by_label) = judged(&refs);
            let (tilt_out, floor_out) = out_share(&refs);
            rows.push(GenRow {
                label_kind: kind.clone(),
                sampling: format!(
                    "{}{}{}{}",
                    sampling_name(sampling),
                    if with_exemplar { " +exemplar" } else { "" },
                    if candidates > 1 && o.rank_every > 0 {
                        format!(" steer-{candidates}-every-{}", o.rank_every)
                    } else if candidates > 1 {
                        format!(" best-of-{candidates}")
                    } else {
                        String::new()
                    },
                    format!(
                        "{}{}",
                        if feet { " +root-from-feet" } else { "" },
                        if pin { " +feet-pinned" } else { "" }
                    )
                ),
                candidates,
                rank_every: if candidates > 1 { o.rank_every } else { 0 },
                labels: values.len(),
                clips: gen.len(),
                fid_k: fid(&rk, &gk),
                fid_g: fid(&rg, &gg),
                fid_k_real,
                fid_g_real,
                fid_k_real_same_n,
                fid_g_real_same_n,
                real_chained: real_chained.clone(),
                fid_k_gaps: feature_gaps(&rk, &gk, GAPS_SHOWN)
                    .into_iter()
                    .map(|g| FeatureGap {
                        feature: kinetic_name(g.feature),
                        z: g.z,
                        spread: g.spread,
                        cost: g.cost,
                    })
                    .collect(),
                fid_k_axis: first_axis(&rk, &gk).map(|a| {
                    let mut by: Vec<usize> = (0..a.loadings.len()).collect();
                    by.sort_by(|&i, &k| a.loadings[k].total_cmp(&a.loadings[i]));
                    KineticAxis {
                        real_share: a.real_share,
                        real_var: a.real_var,
                        gen_var: a.gen_var,
                        shift: a.shift,
                        cost: a.cost,
                        fid_k_without: a.fid_without,
                        fid_k_real_same_n_without,
                        top_features: by.into_iter().take(3).map(kinetic_name).collect(),
                    }
                }),
                fid_k_range: fid_range(&rk, &gk),
                fid_g_range: fid_range(&rg, &gg),
                accel_ratio: mean(gen.iter().map(|r| r.1.accel)) / real_accel.max(1e-12),
                jerk_ratio: mean(gen.iter().map(|r| r.1.jerk)) / real_jerk.max(1e-12),
                skate_ratio: mean(gen.iter().map(|r| r.1.skate)) / real_skate.max(1e-12),
                frozen,
                frozen_real,
                diversity: diversity(&gk, &rk),
                diversity_real: diversity(&rk, &rk),
                cond_acc: overall(&by_window),
                cond_acc_windows: by_window.iter().copied().map(share).collect(),
                cond_acc_real,
                cond_acc_by_label: by_label
                    .into_iter()
                    .map(|(v, hn)| {
                        let real = real_by_label.get(&v).filter(|r| r.1 > 0).map(|&r| share(r));
                        let acc = LabelAcc {
                            generated: share(hn),
                            real,
                        };
                        (v, acc)
                    })
                    .collect(),
                tilt_out,
                tilt_out_real,
                floor_out,
                floor_out_real,
                tilt_max,
                floor_band: [low_lo, low_hi],
                seconds_per_clip: secs,
                seconds_generated: mean(made.iter().map(|m| (m.1.len() / fl) as f64)) / vocab.fps,
                root_in_place: in_place,
            });
        }
    }
    Ok(rows)
}
