//! The frame model's class heads fitted in closed form. The heads trained
//! by gradient alongside the language model (a quarter of the batches)
//! lost to LDA on token-window statistics on every label but one (Bandai
//! content 22 % against 93 %). This module reads each training window
//! through the exported model itself (the runtime's unconditioned walk,
//! exactly what `classify` runs), and fits, per label kind, a shrunk linear
//! discriminant on the window's mean global state. The discriminant is a
//! linear function of the mean state, and the graph's head is one too (the
//! runtime averages the per-frame logits, which equals the head on the
//! mean state), so the fit is written into the graph's `cls.{kind}.w` and
//! `cls.{kind}.b`: no new file and no new runtime path.
//!
//! The shrinkage is chosen per kind by cross-validation on the training
//! windows, grouped by sequence (a sequence's windows and its mirror stay
//! in one fold). The report scores the held-out windows with the old heads,
//! the new ones, LDA on token-window statistics and the majority class, and
//! the same methods by grouped cross-validation on the training side
//! (many more windows than the held-out split has).

use super::data::{self, Sequence};
use super::frame::value_frames;
use crate::features::lda::{window_features, Lda};
use crate::lm::frame_runtime::FrameSession;
use crate::motion::Labels;
use anyhow::{bail, Context, Result};
use prost::Message;
use std::path::Path;

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

/// A linear classifier on raw features: `scores = W x + b`.
#[derive(Clone, Debug)]
/// `scores = W (x − centre) + b` (an empty centre is zero). The graph
/// subtracts the centre before its product too: folded into the bias, the
/// large terms of a barely varying feature would cancel in f32.
pub struct Linear {
    pub weights: Vec<Vec<f64>>,
    pub bias: Vec<f64>,
    pub centre: Vec<f64>,
}

impl Linear {
    pub fn scores(&self, x: &[f64]) -> Vec<f64> {
        let c = |i: usize| self.centre.get(i).copied().unwrap_or(0.0);
        self.weights
            .iter()
            .zip(&self.bias)
            .map(|(w, b)| {
                w.iter()
                    .zip(x)
                    .enumerate()
                    .map(|(i, (a, v))| a * (v - c(i)))
                    .sum::<f64>()
                    + b
            })
            .collect()
    }

    pub fn predict(&self, x: &[f64]) -> usize {
        self.scores(x)
            .into_iter()
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |b, (i, s)| if s > b.1 { (i, s) } else { b },
            )
            .0
    }
}

/// Shrunk LDA on standardised features, folded back onto the raw ones
/// (so the result applies to unscaled features, as a graph head must).
pub fn fit_lda(x: &[Vec<f64>], y: &[usize], classes: usize, shrink: f64) -> Option<Linear> {
    let p = x.first()?.len();
    let n = x.len() as f64;
    let mut mu = vec![0.0; p];
    for xi in x {
        mu.iter_mut().zip(xi).for_each(|(m, v)| *m += v / n);
    }
    let mut sd = vec![0.0; p];
    for xi in x {
        sd.iter_mut()
            .zip(xi.iter().zip(&mu))
            .for_each(|(s, (v, m))| *s += (v - m).powi(2) / n);
    }
    let sd: Vec<f64> = sd.iter().map(|v| v.sqrt()).collect();
    // A feature that does not vary in training (a slot the data never
    // moves) carries nothing, and its weight would be 1/sd: left out.
    let z: Vec<Vec<f64>> = x
        .iter()
        .map(|xi| {
            xi.iter()
                .zip(mu.iter().zip(&sd))
                .map(|(v, (m, &s))| if s > MIN_SD { (v - m) / s } else { 0.0 })
                .collect()
        })
        .collect();
    let lda = Lda::fit(&z, y, classes, shrink)?;
    let mut weights = Vec::with_capacity(classes);
    let mut bias = Vec::with_capacity(classes);
    for (w, o) in lda.weights.iter().zip(&lda.offsets) {
        let raw: Vec<f64> = w
            .iter()
            .zip(&sd)
            .map(|(a, &s)| if s > MIN_SD { a / s } else { 0.0 })
            .collect();
        // An unseen class has offset −∞; keep it finite for the graph and
        // far below any seen class.
        bias.push(if o.is_finite() { *o } else { -1e4 });
        weights.push(raw);
    }
    Some(Linear {
        weights,
        bias,
        centre: mu,
    })
}

/// Features with a smaller training standard deviation are left out.
pub const MIN_SD: f64 = 1e-6;

/// Shrinkage candidates for the cross-validated choice.
pub const SHRINKS: [f64; 7] = [0.001, 0.01, 0.03, 0.1, 0.3, 0.6, 0.9];

/// Grouped k-fold accuracy of `fit` (folds by group number).
pub fn grouped_cv(
    x: &[Vec<f64>],
    y: &[usize],
    groups: &[usize],
    folds: usize,
    fit: impl Fn(&[Vec<f64>], &[usize]) -> Option<Linear>,
) -> f64 {
    grouped_cv_scores(x, y, groups, folds, fit).0
}

/// [`grouped_cv`], with each row's out-of-fold scores (`None` where its
/// fold's fit failed or its fold's training side lacks its class).
pub fn grouped_cv_scores(
    x: &[Vec<f64>],
    y: &[usize],
    groups: &[usize],
    folds: usize,
    fit: impl Fn(&[Vec<f64>], &[usize]) -> Option<Linear>,
) -> (f64, Vec<Option<Vec<f64>>>) {
    let fold = |g: usize| (g.wrapping_mul(2_654_435_761) >> 7) % folds;
    let (mut hit, mut n) = (0usize, 0usize);
    let mut out = vec![None; x.len()];
    for f in 0..folds {
        let (mut tx, mut ty) = (Vec::new(), Vec::new());
        for ((xi, &yi), &g) in x.iter().zip(y).zip(groups) {
            if fold(g) != f {
                tx.push(xi.clone());
                ty.push(yi);
            }
        }
        let Some(m) = fit(&tx, &ty) else { continue };
        for (i, ((xi, &yi), &g)) in x.iter().zip(y).zip(groups).enumerate() {
            if fold(g) == f {
                n += 1;
                hit += (m.predict(xi) == yi) as usize;
                // A class the fold never saw cannot be scored fairly
                // (its offset is a large negative constant): left out of
                // the scores, still a miss in the accuracy.
                if ty.contains(&yi) {
                    out[i] = Some(m.scores(xi));
                }
            }
        }
    }
    (hit as f64 / n.max(1) as f64, out)
}

/// Mean negative log-likelihood (nats) of `y` under softmax(`scores / t`).
pub fn log_loss(scores: &[Option<Vec<f64>>], y: &[usize], t: f64) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (s, &c) in scores.iter().zip(y) {
        let Some(s) = s else { continue };
        let m = s.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b / t));
        let lse = m + s.iter().map(|&v| (v / t - m).exp()).sum::<f64>().ln();
        sum += lse - s[c] / t;
        n += 1;
    }
    sum / n.max(1) as f64
}

/// The temperature (on a log grid from 0.25 to 4,096) whose softmax of
/// the out-of-fold scores has the least log-loss: a discriminant's raw
/// scores on hundreds of features are far too sure of themselves, and the
/// served probabilities should mean what they say. Returns (temperature,
/// log-loss at it, log-loss at 1).
pub fn calibrate(scores: &[Option<Vec<f64>>], y: &[usize]) -> (f64, f64, f64) {
    let at1 = log_loss(scores, y, 1.0);
    (0..=56)
        .map(|i| 0.25 * 2f64.powf(i as f64 / 4.0))
        .map(|t| (t, log_loss(scores, y, t)))
        .fold(
            (1.0, at1, at1),
            |b, (t, l)| if l < b.1 { (t, l, at1) } else { b },
        )
}

impl Linear {
    /// Divides every score by `t` (the argmax is unchanged).
    pub fn tempered(mut self, t: f64) -> Linear {
        for w in self.weights.iter_mut() {
            w.iter_mut().for_each(|v| *v /= t);
        }
        self.bias.iter_mut().for_each(|v| *v /= t);
        self
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

impl From<Lda> for Linear {
    fn from(l: Lda) -> Linear {
        Linear {
            weights: l.weights,
            bias: l
                .offsets
                .into_iter()
                .map(|o| if o.is_finite() { o } else { -1e4 })
                .collect(),
            centre: Vec::new(),
        }
    }
}

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
    /// The fitted head (the method with the head's features) on them.
    pub new_head: f64,
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
            let (shrink, cv) = grid
                .iter()
                .map(|&s| (s, grouped_cv(&tx, &ty, &tg, 5, |x, y| fit(x, y, s))))
                .fold((grid[0], -1.0), |b, c| if c.1 > b.1 { c } else { b });
            let mut model = fit(&tx, &ty, shrink).context("the discriminant has no solution")?;
            let is_head = f == head_features && !baseline;
            if is_head {
                let (_, oof) = grouped_cv_scores(&tx, &ty, &tg, 5, |x, y| fit(x, y, shrink));
                let (t, loss, loss1) = calibrate(&oof, &ty);
                calibration = Some(Calibration {
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
            if is_head {
                head = Some(model);
                new_head = acc(hits);
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
            calibration,
            methods,
        });
    }
    Ok((reports, heads))
}

/// Sets an initialiser's data, checking its shape.
fn set_init(
    graph: &mut tract_onnx::pb::GraphProto,
    name: &str,
    dims: &[i64],
    data: &[f32],
) -> Result<()> {
    let init = graph
        .initializer
        .iter_mut()
        .find(|t| t.name == name)
        .with_context(|| format!("the global graph has no initialiser {name}"))?;
    if init.dims != dims {
        bail!(
            "{name}: the graph's shape {:?}, the fit's {:?}",
            init.dims,
            dims
        );
    }
    init.float_data.clear();
    init.raw_data = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    Ok(())
}

/// Writes the fitted heads into the global graph's bytes. Every head's
/// state path becomes `(h − cls.{kind}.ch) · cls.{kind}.w + cls.{kind}.b`
/// (a `Sub` before the head's `MatMul`). A head on the state and the pose
/// statistics (`d_global + 3 · slots` features) also gets a pose path: the
/// state path's sum is renamed `cls_{kind}_state`, and `cls_{kind}` adds
/// `(v − cv) · wv + (v² − cv2) · wv2 + (m − cm) · wm` (all `cls.{kind}.*`),
/// with `v = val / bins` and `m` the change code's magnitude over `bins` (a
/// table lookup on `chg`): the per-step terms of [`pose_stats`]. A graph
/// that already has these paths only gets new weights; a state-only head
/// cannot replace a pose path.
pub fn rewrite_heads(
    onnx: &[u8],
    cfg: &crate::lm::frame::FrameConfig,
    heads: &[Option<Linear>],
) -> Result<Vec<u8>> {
    use super::export::{attr_i, Builder, DataType};
    let (d, slots) = (cfg.d_global, cfg.slots);
    let mut proto =
        tract_onnx::pb::ModelProto::decode(onnx).context("the global graph is not ONNX")?;
    let graph = proto
        .graph
        .as_mut()
        .context("the global graph has no graph")?;
    let has = |g: &tract_onnx::pb::GraphProto, n: &str| g.initializer.iter().any(|t| t.name == n);
    let mut tail = Builder::default();
    let mut shared = false;
    for ((kind, values), head) in cfg.classes.iter().zip(heads) {
        let Some(h) = head else { continue };
        let nc = values.len();
        let width = h.weights.first().map_or(0, |w| w.len());
        let pose = match width {
            w if w == d => false,
            w if w == d + 3 * slots => true,
            w => bail!(
                "{kind}: a head of {w} features fits neither the state ({d}) nor the state and pose ({})",
                d + 3 * slots
            ),
        };
        let name = |n: &str| format!("cls.{kind}.{n}");
        if !pose && has(graph, &name("wv")) {
            bail!("{kind}: the graph has a pose path; a state-only head cannot replace it");
        }
        // Rows = features (from `from`, every `step`-th), columns = classes.
        let block = |from: usize, rows: usize, step: usize| -> Vec<f32> {
            let mut out = vec![0f32; rows * nc];
            for (c, row) in h.weights.iter().enumerate() {
                for r in 0..rows {
                    out[r * nc + c] = row[from + r * step] as f32;
                }
            }
            out
        };
        let centre = |from: usize, rows: usize, step: usize| -> Vec<f32> {
            (0..rows)
                .map(|r| h.centre.get(from + r * step).copied().unwrap_or(0.0) as f32)
                .collect()
        };
        let b: Vec<f32> = h.bias.iter().map(|&v| v as f32).collect();
        set_init(graph, &name("w"), &[d as i64, nc as i64], &block(0, d, 1))?;
        set_init(graph, &name("b"), &[nc as i64], &b)?;
        if has(graph, &name("ch")) {
            set_init(graph, &name("ch"), &[d as i64], &centre(0, d, 1))?;
        } else {
            // Centre the state before the head's product.
            let w = name("w");
            let at = graph
                .node
                .iter()
                .position(|n| n.op_type == "MatMul" && n.input.iter().any(|i| *i == w))
                .with_context(|| format!("the global graph has no MatMul reading {w}"))?;
            let x = graph.node[at]
                .input
                .iter()
                .find(|i| **i != w)
                .cloned()
                .context("the head's MatMul has one input")?;
            let mut pre = Builder::default();
            pre.f32(&name("ch"), &[d], centre(0, d, 1));
            let hc = format!("cls_{kind}_centred");
            pre.op("Sub", &[&x, &name("ch")], vec![], Some(&hc));
            graph.node[at]
                .input
                .iter_mut()
                .filter(|i| **i == x)
                .for_each(|i| *i = hc.clone());
            let mut sub = pre.nodes.pop().expect("one node");
            sub.name = format!("cls_{kind}_centre_Sub");
            graph.node.insert(at, sub);
            graph.initializer.extend(pre.inits);
        }
        if !pose {
            continue;
        }
        let ws = ["wv", "wv2", "wm"].map(name);
        let cs = ["cv", "cv2", "cm"].map(name);
        let wblocks = [
            block(d, slots, 3),
            block(d + 1, slots, 3),
            block(d + 2, slots, 3),
        ];
        let cblocks = [
            centre(d, slots, 3),
            centre(d + 1, slots, 3),
            centre(d + 2, slots, 3),
        ];
        if has(graph, &ws[0]) {
            for (n, w) in ws.iter().zip(&wblocks) {
                set_init(graph, n, &[slots as i64, nc as i64], w)?;
            }
            for (n, c) in cs.iter().zip(&cblocks) {
                set_init(graph, n, &[slots as i64], c)?;
            }
            continue;
        }
        let out = format!("cls_{kind}");
        let state = format!("cls_{kind}_state");
        let node = graph
            .node
            .iter_mut()
            .find(|n| n.output.iter().any(|o| *o == out))
            .with_context(|| format!("the global graph has no node giving {out}"))?;
        node.output
            .iter_mut()
            .filter(|o| **o == out)
            .for_each(|o| *o = state.clone());
        let g = &mut tail;
        if !shared {
            shared = true;
            let mags: Vec<f32> = (0..cfg.change_rows() as u32)
                .map(|c| (change_magnitude(cfg, c) / cfg.bins as f64) as f32)
                .collect();
            g.f32("pose_mag_table", &[mags.len()], mags);
            g.scalar("pose_inv_bins", 1.0 / cfg.bins as f32);
            let vf = g.op(
                "Cast",
                &["val"],
                vec![attr_i("to", DataType::Float as i64)],
                Some("pose_val_f"),
            );
            g.op("Mul", &[&vf, "pose_inv_bins"], vec![], Some("pose_v"));
            g.op("Mul", &["pose_v", "pose_v"], vec![], Some("pose_v2"));
            g.op(
                "Gather",
                &["pose_mag_table", "chg"],
                vec![attr_i("axis", 0)],
                Some("pose_m"),
            );
        }
        let mut sum = state.clone();
        for (i, (src, part)) in [("pose_v", "v"), ("pose_v2", "v2"), ("pose_m", "m")]
            .into_iter()
            .enumerate()
        {
            g.f32(&ws[i], &[slots, nc], wblocks[i].clone());
            g.f32(&cs[i], &[slots], cblocks[i].clone());
            let c = g.op(
                "Sub",
                &[src, &cs[i]],
                vec![],
                Some(&format!("pose_{kind}_{part}_c")),
            );
            let t = g.op(
                "MatMul",
                &[&c, &ws[i]],
                vec![],
                Some(&format!("pose_{kind}_{part}")),
            );
            let o = if i == 2 {
                out.clone()
            } else {
                format!("pose_{kind}_{part}_sum")
            };
            sum = g.op("Add", &[&sum, &t], vec![], Some(&o));
        }
    }
    for (i, mut n) in tail.nodes.into_iter().enumerate() {
        n.name = format!("pose_{i}_{}", n.op_type);
        graph.node.push(n);
    }
    graph.initializer.extend(tail.inits);
    Ok(proto.encode_to_vec())
}

/// Copies a frame model folder to `out` with the fitted heads written into
/// its global graph, the manifest's hash updated and the report kept in its
/// training record; then loads the copy and checks that its `classify`
/// agrees with the fitted discriminants on `check` windows.
pub fn write_model(
    model: &Path,
    out: &Path,
    heads: &[Option<Linear>],
    report: &serde_json::Value,
    check: &[HeadWindow],
    features: Features,
    engine: &crate::lm::engine::Engine,
) -> Result<()> {
    use crate::lm::frame::FrameManifest;
    let (mut m, global, _) = FrameManifest::load(model)?;
    std::fs::create_dir_all(out)?;
    for e in std::fs::read_dir(model)? {
        let e = e?;
        if e.file_type()?.is_file() {
            std::fs::copy(e.path(), out.join(e.file_name()))?;
        }
    }
    let bytes = rewrite_heads(&global, &m.config, heads)?;
    std::fs::write(out.join(&m.global_onnx), &bytes)?;
    m.global_sha256 = crate::lm::manifest::sha256_hex(&bytes);
    if let serde_json::Value::Object(t) = &mut m.training {
        t.insert("class_heads".into(), report.clone());
    }
    for (k, acc, n) in report["kinds"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|r| {
            Some((
                r["kind"].as_str()?.to_string(),
                r["new_head"].as_f64()?,
                r["held_out_windows"].as_f64()?,
            ))
        })
    {
        m.metrics.insert(format!("val_accuracy_{k}"), acc);
        m.metrics.insert(format!("val_windows_{k}"), n);
    }
    std::fs::write(out.join("manifest.json"), serde_json::to_vec_pretty(&m)?)?;
    let s = FrameSession::load_with(out, engine)?;
    for w in check {
        let (values, state) = (&w.values, &features.of(w));
        let logits = s.classify(values)?;
        for ((l, h), (k, _)) in logits.iter().zip(heads).zip(&m.config.classes) {
            let Some(h) = h else { continue };
            for (c, want) in h.scores(state).into_iter().enumerate() {
                let got = l[c] as f64;
                if (want - got).abs() > 1e-3 * (1.0 + want.abs()) {
                    bail!("{k} class {c}: the written graph gives {got}, the fit {want}");
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The discriminant folded back onto raw features scores exactly as the
    /// one on standardised features, and separates blobs whose scales
    /// differ by orders of magnitude.
    #[test]
    fn folded_lda_matches_the_standardised_one() {
        let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(3);
        use rand::Rng;
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for i in 0..300 {
            let c = i % 3;
            let centre = [c as f64 * 1e3, -(c as f64) * 1e-3, 5.0];
            let scale = [300.0, 3e-4, 1.0];
            x.push(
                (0..3)
                    .map(|j| centre[j] + scale[j] * (rng.gen::<f64>() - 0.5))
                    .collect::<Vec<f64>>(),
            );
            y.push(c);
        }
        let raw = fit_lda(&x, &y, 3, 0.1).unwrap();
        let hits = x
            .iter()
            .zip(&y)
            .filter(|(xi, &c)| raw.predict(xi) == c)
            .count();
        assert!(hits >= 290, "{hits} of 300");
        // The same scores as the discriminant fitted on z-scores.
        let n = x.len() as f64;
        let mu: Vec<f64> = (0..3)
            .map(|j| x.iter().map(|r| r[j]).sum::<f64>() / n)
            .collect();
        let sd: Vec<f64> = (0..3)
            .map(|j| (x.iter().map(|r| (r[j] - mu[j]).powi(2)).sum::<f64>() / n).sqrt())
            .collect();
        let z: Vec<Vec<f64>> = x
            .iter()
            .map(|r| (0..3).map(|j| (r[j] - mu[j]) / sd[j]).collect())
            .collect();
        let std = Lda::fit(&z, &y, 3, 0.1).unwrap();
        for (xi, zi) in x.iter().zip(&z) {
            let scores = raw.scores(xi);
            for c in 0..3 {
                let a = scores[c];
                let b = std.weights[c]
                    .iter()
                    .zip(zi)
                    .map(|(w, v)| w * v)
                    .sum::<f64>()
                    + std.offsets[c];
                assert!((a - b).abs() < 1e-6 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
    }

    /// Cross-validation keeps a group's rows in one fold: a "classifier"
    /// that memorises groups scores nothing on unseen ones.
    #[test]
    fn grouped_folds_hold_out_whole_groups() {
        // Each group has its own class, and the feature is the group id:
        // a fit can only recall groups it saw.
        let groups: Vec<usize> = (0..40).map(|i| i / 4).collect();
        let y: Vec<usize> = groups.clone();
        let x: Vec<Vec<f64>> = groups.iter().map(|&g| vec![g as f64]).collect();
        let acc = grouped_cv(&x, &y, &groups, 5, |_, ty| {
            // Predicts only classes it was trained on.
            let mut bias = vec![f64::NEG_INFINITY; 10];
            ty.iter().for_each(|&c| bias[c] = 0.0);
            Some(Linear {
                weights: vec![vec![0.0]; 10],
                bias,
                centre: Vec::new(),
            })
        });
        assert!(acc < 0.01, "{acc}");
    }
}

#[cfg(test)]
mod calibration_tests {
    use super::*;

    /// Scores a hundred times too sure, right four times in five: the
    /// chosen temperature brings the log-loss down near the best possible.
    #[test]
    fn temperature_undoes_overconfidence() {
        let y: Vec<usize> = (0..200).map(|i| i % 2).collect();
        let scores: Vec<Option<Vec<f64>>> = y
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let right = i % 5 != 0;
                let top = if right { c } else { 1 - c };
                let mut s = vec![0.0; 2];
                s[top] = 100.0 * 1.386; // ln 4 = log-odds of 80 %, ×100
                Some(s)
            })
            .collect();
        let (t, loss, loss1) = calibrate(&scores, &y);
        assert!(loss1 > 20.0, "{loss1}");
        // Best possible: the entropy of 80/20, 0.500 nats, at t = 100.
        assert!((loss - 0.5004).abs() < 0.01, "{loss} at {t}");
        assert!((60.0..170.0).contains(&t), "{t}");
    }
}
