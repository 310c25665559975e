//! The frame model's class heads fitted in closed form. The heads trained
//! by gradient alongside the language model (a quarter of the batches)
//! lost to LDA on token-window statistics on every label but one (Bandai
//! content 22 % against 93 %). `choreo-train fit-heads` reads each training
//! window through the exported model itself (the runtime's unconditioned
//! walk, exactly what `classify` runs) and fits, per label kind, a shrunk
//! linear discriminant on the window's mean global state and per-step pose
//! statistics of the graph's own inputs ([`pose_stats`]). Both are means
//! over frames of one step's quantities, and the runtime averages the
//! per-frame logits, so the fit is a per-step head: [`graph`] writes it
//! into the global graph (no new file, no new runtime path).
//!
//! The shrinkage is chosen per kind by cross-validation on the training
//! windows grouped by sequence (a sequence's windows and its mirror stay in
//! one fold), and the head's scores are tempered into probabilities on the
//! out-of-fold scores ([`linear`]). The report scores the held-out windows
//! with the old heads, the new ones, LDA on token-window statistics and
//! the majority class, and the same methods by grouped cross-validation on
//! the training side (many more windows than the held-out split has).

pub mod graph;
pub mod linear;

pub use graph::{add_head_slots, rewrite_heads, write_model};
pub use linear::{
    calibrate, fit_lda, grouped_cv, grouped_cv_scores, log_loss, Linear, MIN_SD, SHRINKS,
};

use super::data::{self, Sequence};
use super::frame::value_frames;
use crate::features::lda::{window_features, Lda};
use crate::lm::frame_runtime::FrameSession;
use crate::motion::Labels;
use anyhow::{Context, Result};

/// One window as the fits see it.
pub struct HeadWindow {
    /// The model's mean global state over the window (`d_global`).
    pub state: Vec<f64>,
    /// The model's mean absolute frame-to-frame state change (`d_global`).
    pub state_change: Vec<f64>,
    /// LDA's token-window statistics (the Table 4.8 baseline's features).
    pub stats: Vec<f64>,
    /// What a head can average from the graph's per-frame inputs, per
    /// slot: the mean bin, the mean squared bin (both over `bins`) and the
    /// mean change magnitude (the change code's, capped at `radius + 1`,
    /// 0 at the window's first frame; over `bins`). See [`pose_stats`].
    pub pose: Vec<f64>,
    pub labels: Labels,
    /// The sequence it came from (its mirror shares the number).
    pub group: usize,
    /// The window's value tokens (`slots` a frame), to run it again.
    pub values: Vec<u32>,
}

/// Every context window of `seqs` (and of their mirrors when `mirrors`),
/// read through the model, on `threads` threads.
pub fn read_windows(
    session: &FrameSession,
    seqs: &[Sequence],
    fl: usize,
    bins: usize,
    mirrors: bool,
    threads: usize,
) -> Result<Vec<HeadWindow>> {
    let w = session.config().max_frames;
    let d = session.config().d_global;
    let mut jobs: Vec<(&[u32], &Labels, usize)> = Vec::new();
    for (g, s) in seqs.iter().enumerate() {
        let mut sides = vec![s.tokens.as_slice()];
        if mirrors {
            sides.extend(s.mirrored.as_deref());
        }
        for toks in sides {
            let n = toks.len() / fl;
            for (st, len) in data::cuts(n, w) {
                // A stub at a sequence's end says little about its labels.
                if len * 4 < w.min(n) {
                    continue;
                }
                jobs.push((&toks[st * fl..(st + len) * fl], &s.labels, g));
            }
        }
    }
    let threads = threads.max(1);
    let per = jobs.len().div_ceil(threads).max(1);
    let parts: Vec<Result<Vec<HeadWindow>>> = std::thread::scope(|sc| {
        let handles: Vec<_> = jobs
            .chunks(per)
            .map(|chunk| {
                sc.spawn(move || {
                    chunk
                        .iter()
                        .map(|&(toks, labels, group)| {
                            let values = value_frames(toks, fl);
                            let pooled = session.pooled_states(&values)?;
                            let pose = pose_stats(&values, session.config());
                            Ok(HeadWindow {
                                values,
                                state: pooled[..d].iter().map(|&v| v as f64).collect(),
                                state_change: pooled[d..].iter().map(|&v| v as f64).collect(),
                                stats: window_features(toks, fl, bins),
                                pose,
                                labels: labels.clone(),
                                group,
                            })
                        })
                        .collect()
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("window reader panicked"))
            .collect()
    });
    let mut out = Vec::with_capacity(jobs.len());
    for p in parts {
        out.extend(p?);
    }
    Ok(out)
}

/// Per slot: mean of `v / bins`, of `(v / bins)²`, and of the change
/// magnitude over `bins`, where the magnitude is read from the change code
/// the graph receives (`|offset|` inside the radius, `radius + 1` for an
/// escape, 0 for "no previous frame"). Each is a mean over frames of a
/// function of one step's inputs, so a per-step head can hold it.
pub fn pose_stats(values: &[u32], cfg: &crate::lm::frame::FrameConfig) -> Vec<f64> {
    let s = cfg.slots;
    let n = values.len() / s;
    let b = cfg.bins as f64;
    let mut out = vec![0.0; 3 * s];
    for f in 0..n {
        let cur = &values[f * s..(f + 1) * s];
        let p1 = (f > 0).then(|| &values[(f - 1) * s..f * s]);
        let chg = crate::lm::frame::frame_changes(cfg, cur, p1);
        for k in 0..s {
            let v = cur[k] as f64 / b;
            out[3 * k] += v;
            out[3 * k + 1] += v * v;
            out[3 * k + 2] += change_magnitude(cfg, chg[k]) / b;
        }
    }
    out.iter_mut().for_each(|x| *x /= n.max(1) as f64);
    out
}

/// The magnitude, in bins, a change code stands for.
pub fn change_magnitude(cfg: &crate::lm::frame::FrameConfig, code: u32) -> f64 {
    let r = cfg.radius as i64;
    let c = code as i64;
    if c <= 2 * r {
        (c - r).unsigned_abs() as f64
    } else if code == cfg.esc() {
        (r + 1) as f64
    } else {
        0.0
    }
}

/// Features of one window for a method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Features {
    /// The model's mean state: what the graph's head can hold.
    State,
    /// Mean state and mean state change (the `lm` search embedding).
    StateAndChange,
    /// LDA's token-window statistics.
    Stats,
    /// [`pose_stats`].
    Pose,
    /// Mean state and [`pose_stats`]: what the graph's head holds.
    StateAndPose,
}

impl Features {
    pub fn name(self) -> &'static str {
        match self {
            Features::State => "mean state",
            Features::StateAndChange => "mean state + state change",
            Features::Stats => "token-window statistics",
            Features::Pose => "per-step pose statistics",
            Features::StateAndPose => "mean state + per-step pose statistics",
        }
    }

    pub fn of(self, w: &HeadWindow) -> Vec<f64> {
        match self {
            Features::State => w.state.clone(),
            Features::StateAndChange => [w.state.as_slice(), &w.state_change].concat(),
            Features::Stats => w.stats.clone(),
            Features::Pose => w.pose.clone(),
            Features::StateAndPose => [w.state.as_slice(), &w.pose].concat(),
        }
    }
}

/// The methods every report scores, in its order: (features, the Table
/// 4.8 baseline's own fit).
pub const METHODS: [(Features, bool); 6] = [
    (Features::Stats, true),
    (Features::Stats, false),
    (Features::State, false),
    (Features::StateAndChange, false),
    (Features::Pose, false),
    (Features::StateAndPose, false),
];

/// One kind's labelled windows as (features, class, group).
fn labelled(
    ws: &[HeadWindow],
    kind: &str,
    values: &[String],
    f: Features,
) -> (Vec<Vec<f64>>, Vec<usize>, Vec<usize>) {
    let (mut x, mut y, mut g) = (Vec::new(), Vec::new(), Vec::new());
    for w in ws {
        if let Some(c) = w
            .labels
            .get(kind)
            .and_then(|v| values.iter().position(|x| x == v))
        {
            x.push(f.of(w));
            y.push(c);
            g.push(w.group);
        }
    }
    (x, y, g)
}

/// A method's figures for one kind.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MethodScore {
    pub features: &'static str,
    /// The Table 4.8 baseline's fit (raw features, shrinkage 0.1); else
    /// standardised features, shrinkage by cross-validation.
    pub baseline: bool,
    pub shrink: f64,
    /// Grouped 5-fold accuracy on the training windows.
    pub train_cv: f64,
    /// Accuracy on the held-out windows (fitted on all training windows).
    pub held_out: f64,
}

/// How the head's scores were tempered into probabilities.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Calibration {
    pub temperature: f64,
    /// Out-of-fold log-loss (nats) at that temperature, and untempered.
    pub cv_log_loss: f64,
    pub cv_log_loss_untempered: f64,
}

/// One kind's row of the report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct KindReport {
    pub kind: String,
    pub train_windows: usize,
    pub held_out_windows: usize,
    pub majority: f64,
    /// The graph's current head on the held-out windows.
    pub current_head: f64,
    /// The fitted head on them.
    pub new_head: f64,
    /// The features the written head reads: for a state-and-pose head,
    /// whichever of that and the pose statistics alone scored higher in
    /// grouped cross-validation on the training windows (ties: state and
    /// pose); a pose-only head is written with zero state weights.
    #[serde(default)]
    pub head_features: String,
    /// The head's temperature, chosen on out-of-fold training scores.
    pub calibration: Option<Calibration>,
    pub methods: Vec<MethodScore>,
}

/// Fits every kind's head on the mean state and scores all methods.
/// Returns the report and, per kind (manifest order; `None` where the
/// training side has no labelled window), the head to write.
pub fn fit_heads(
    session: &FrameSession,
    train: &[HeadWindow],
    held_out: &[HeadWindow],
    head_features: Features,
) -> Result<(Vec<KindReport>, Vec<Option<Linear>>)> {
    let classes = session.config().classes.clone();
    // The current graph's answers on the held-out windows.
    let mut current: Vec<Vec<usize>> = Vec::with_capacity(held_out.len());
    for w in held_out {
        let logits = session.classify(&w.values)?;
        current.push(
            logits
                .iter()
                .map(|l| {
                    l.iter()
                        .enumerate()
                        .fold(
                            (0, f32::NEG_INFINITY),
                            |b, (i, &v)| if v > b.1 { (i, v) } else { b },
                        )
                        .0
                })
                .collect(),
        );
    }
    let mut reports = Vec::new();
    let mut heads = Vec::new();
    for (ki, (kind, values)) in classes.iter().enumerate() {
        let nc = values.len();
        let (_, ty, _) = labelled(train, kind, values, Features::State);
        let (_, vy, _) = labelled(held_out, kind, values, Features::State);
        if ty.is_empty() {
            heads.push(None);
            continue;
        }
        let mut counts = vec![0usize; nc];
        ty.iter().for_each(|&c| counts[c] += 1);
        let major = (0..nc).max_by_key(|&c| counts[c]).unwrap_or(0);
        let acc = |hits: usize| hits as f64 / vy.len().max(1) as f64;
        let majority = acc(vy.iter().filter(|&&c| c == major).count());
        let mut cur_hits = 0;
        for (w, pred) in held_out.iter().zip(&current) {
            if let Some(c) = w
                .labels
                .get(kind)
                .and_then(|v| values.iter().position(|x| x == v))
            {
                cur_hits += (pred[ki] == c) as usize;
            }
        }
        let mut methods = Vec::new();
        let mut head = None;
        let mut new_head = 0.0;
        let mut calibration = None;
        let mut head_cv = f64::NEG_INFINITY;
        let mut head_from = head_features.name();
        // The state's width, for padding a pose-only head.
        let d = train.first().map_or(0, |w| w.state.len());
        for (f, baseline) in METHODS {
            let (tx, ty, tg) = labelled(train, kind, values, f);
            let (vx, vy, _) = labelled(held_out, kind, values, f);
            let fit = |x: &[Vec<f64>], y: &[usize], s: f64| {
                if baseline {
                    Lda::fit(x, y, nc, s).map(Linear::from)
                } else {
                    fit_lda(x, y, nc, s)
                }
            };
            // The Table 4.8 baseline keeps its shrinkage; the rest choose
            // theirs by cross-validation.
            let grid: &[f64] = if baseline { &[0.1] } else { &SHRINKS };
            // The chosen shrinkage's out-of-fold scores also set the
            // head's temperature.
            let mut runs = grid.iter().map(|&s| {
                let (acc, oof) = grouped_cv_scores(&tx, &ty, &tg, 5, |x, y| fit(x, y, s));
                (s, acc, oof)
            });
            let first = runs.next().expect("a shrinkage grid");
            let (shrink, cv, oof) = runs.fold(first, |b, c| if c.1 > b.1 { c } else { b });
            let mut model = fit(&tx, &ty, shrink).context("the discriminant has no solution")?;
            let is_head = !baseline
                && (f == head_features
                    || (head_features == Features::StateAndPose && f == Features::Pose));
            let mut cal = None;
            if is_head {
                let (t, loss, loss1) = calibrate(&oof, &ty);
                cal = Some(Calibration {
                    temperature: t,
                    cv_log_loss: loss,
                    cv_log_loss_untempered: loss1,
                });
                model = model.tempered(t);
            }
            let hits = vx
                .iter()
                .zip(&vy)
                .filter(|(x, &y)| model.predict(x) == y)
                .count();
            if is_head && (cv > head_cv || (cv == head_cv && f == head_features)) {
                head_cv = cv;
                head_from = f.name();
                calibration = cal;
                new_head = acc(hits);
                head = Some(if f == head_features {
                    model
                } else {
                    model.padded_front(d)
                });
            }
            methods.push(MethodScore {
                features: f.name(),
                baseline,
                shrink,
                train_cv: cv,
                held_out: acc(hits),
            });
        }
        heads.push(head);
        reports.push(KindReport {
            kind: kind.clone(),
            train_windows: ty.len(),
            held_out_windows: vy.len(),
            majority,
            current_head: acc(cur_hits),
            new_head,
            head_features: head_from.to_string(),
            calibration,
            methods,
        });
    }
    Ok((reports, heads))
}
