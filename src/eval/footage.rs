//! The footage evaluation (`choreo eval footage`): keypoints made from real
//! SMPL takes ([`synthesize`]), solved back by inverse kinematics, then
//! - **IK accuracy:** per SMPL-13 joint, the error of the solved local
//!   rotation against the take's, twist about the bone excluded
//!   ([`joint_errors`]), on clean and on noisy keypoints, beside the rest
//!   pose as the trivial baseline;
//! - **cross-modal search:** every window of a take's keypoint version
//!   queries the windows of all the mocap takes (exact cosine search on the
//!   stored embeddings), and the reverse: every mocap window queries the
//!   keypoint versions. Recall@k is over distinct takes (the right take
//!   among the k nearest takes); "same moment" asks the nearest window to
//!   be the right take within ±0.5 s. Chance is 1 / takes.

use super::percentile;
use crate::features::{channels72, window, window_starts, Embedding, Extractor, StftParams};
use crate::index::dot;
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::keypoints::{
    joint_errors, solve, synthesize, Layout, Measure, SolveOptions, SynthOptions,
};
use crate::motion::{Motion, MotionError};
use serde::Serialize;
use std::path::PathBuf;

#[derive(Clone, Debug, Serialize)]
pub struct IkRow {
    pub layout: String,
    pub condition: String,
    pub measure: Measure,
    pub joint: String,
    pub median_deg: f64,
    pub p90_deg: f64,
    pub frames: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct SearchRow {
    pub layout: String,
    pub condition: String,
    /// `keypoints->mocap` or `mocap->keypoints`.
    pub direction: String,
    pub embedding: Embedding,
    pub queries: usize,
    pub recall_at_1: f64,
    pub recall_at_10: f64,
    pub same_moment_at_1: f64,
    pub chance_at_1: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct FootageEval {
    pub takes: usize,
    pub frames: usize,
    pub video_fps: f64,
    pub pelvis_share: Option<f64>,
    pub smooth_s: f64,
    pub ik: Vec<IkRow>,
    pub search: Vec<SearchRow>,
    pub errors: Vec<String>,
}

#[derive(Clone, Debug)]
pub struct FootageEvalOptions {
    pub layouts: Vec<Layout>,
    pub video_fps: f64,
    pub seed: u64,
    /// Overrides each layout's own share.
    pub pelvis_share: Option<f64>,
    pub smooth_s: f64,
    pub embeddings: Vec<Embedding>,
    pub hop: usize,
    /// Skip the search tables (IK accuracy only).
    pub ik_only: bool,
}

/// Windows of one motion, embedded: `(start frame at 60 fps, vector)`.
fn embed_windows(
    m: &Motion,
    e: Embedding,
    ex: &Extractor,
    hop: usize,
) -> Result<Vec<(usize, Vec<f32>)>, MotionError> {
    let ch = channels72(m)?;
    window_starts(ch.len(), hop)
        .into_iter()
        .map(|s| Ok((s, ex.embed(e, &window(&ch, s), None)?)))
        .collect()
}

fn ik_rows(
    layout: Layout,
    condition: &str,
    measure: Measure,
    errs: Vec<(String, Vec<f64>)>,
) -> Vec<IkRow> {
    let mut all = Vec::new();
    let mut rows: Vec<IkRow> = errs
        .into_iter()
        .map(|(joint, mut e)| {
            e.retain(|v| v.is_finite());
            e.sort_by(f64::total_cmp);
            all.extend_from_slice(&e);
            IkRow {
                layout: layout.name().into(),
                condition: condition.into(),
                measure,
                joint,
                median_deg: percentile(&e, 0.5),
                p90_deg: percentile(&e, 0.9),
                frames: e.len(),
            }
        })
        .collect();
    all.sort_by(f64::total_cmp);
    rows.push(IkRow {
        layout: layout.name().into(),
        condition: condition.into(),
        measure,
        joint: "all".into(),
        median_deg: percentile(&all, 0.5),
        p90_deg: percentile(&all, 0.9),
        frames: all.len(),
    });
    rows
}

/// Merge per-take joint errors into one list per joint.
fn merge(acc: &mut Vec<(String, Vec<f64>)>, take: Vec<(String, Vec<f64>)>) {
    if acc.is_empty() {
        *acc = take;
        return;
    }
    for ((_, a), (_, b)) in acc.iter_mut().zip(take) {
        a.extend(b);
    }
}

/// Exact cosine search of every query window against a corpus of takes.
/// Returns (recall@1, recall@10, same-moment@1, queries).
fn cross_search(
    queries: &[Vec<(usize, Vec<f32>)>],
    corpus: &[Vec<(usize, Vec<f32>)>],
) -> (f64, f64, f64, usize) {
    let flat: Vec<(usize, usize, &[f32], f32)> = corpus
        .iter()
        .enumerate()
        .flat_map(|(t, ws)| {
            ws.iter()
                .map(move |(s, v)| (t, *s, v.as_slice(), dot(v, v).sqrt().max(1e-30)))
        })
        .collect();
    let jobs: Vec<(usize, usize, &[f32])> = queries
        .iter()
        .enumerate()
        .flat_map(|(t, ws)| ws.iter().map(move |(s, v)| (t, *s, v.as_slice())))
        .collect();
    let takes = corpus.len();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let chunk = jobs.len().div_ceil(threads).max(1);
    let counts = std::thread::scope(|sc| {
        let handles: Vec<_> = jobs
            .chunks(chunk)
            .map(|part| {
                let flat = &flat;
                sc.spawn(move || {
                    let (mut r1, mut r10, mut same) = (0usize, 0usize, 0usize);
                    let mut best = vec![f32::INFINITY; takes];
                    for &(truth, start, q) in part {
                        best.iter_mut().for_each(|b| *b = f32::INFINITY);
                        let qn = dot(q, q).sqrt().max(1e-30);
                        let mut top = (f32::INFINITY, usize::MAX, 0usize);
                        for &(t, s, v, vn) in flat {
                            let d = 1.0 - dot(q, v) / (qn * vn);
                            if d < best[t] {
                                best[t] = d;
                            }
                            if d < top.0 {
                                top = (d, t, s);
                            }
                        }
                        let rank = 1 + best.iter().filter(|&&b| b < best[truth]).count();
                        r1 += (rank == 1) as usize;
                        r10 += (rank <= 10) as usize;
                        same += (top.1 == truth && top.2.abs_diff(start) <= 30) as usize;
                    }
                    (r1, r10, same)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("search worker"))
            .fold((0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2))
    });
    let n = jobs.len().max(1) as f64;
    (
        counts.0 as f64 / n,
        counts.1 as f64 / n,
        counts.2 as f64 / n,
        jobs.len(),
    )
}

/// A motion turned about the vertical by `deg` (root orientation only; the
/// IK errors compare rotations).
fn turned(m: &Motion, deg: f64) -> Motion {
    use crate::motion::rotation::{axis_angle_to_quat, quat_mul, quat_to_axis_angle};
    if deg == 0.0 {
        return m.clone();
    }
    let yaw = axis_angle_to_quat([0.0, deg.to_radians(), 0.0]);
    let j = m.joints();
    let mut rots = m.rotations.clone();
    for f in 0..m.frames() {
        rots[f * j] = quat_to_axis_angle(quat_mul(yaw, axis_angle_to_quat(rots[f * j])));
    }
    m.with_data(m.trans.clone(), rots)
}

pub fn evaluate(files: &[PathBuf], opts: &FootageEvalOptions) -> FootageEval {
    let mut errors = Vec::new();
    let mut takes: Vec<Motion> = Vec::new();
    for f in files {
        match read_path(f, &ReadOptions::default())
            .and_then(|l| crate::features::smpl24_at_60(&l.motion))
        {
            Ok(m) => takes.push(m),
            Err(e) => errors.push(e.to_string()),
        }
    }
    let ex = Extractor::new(StftParams::default()).expect("default STFT");
    let mut ik = Vec::new();
    let mut search = Vec::new();
    let frames = takes.iter().map(|m| m.frames()).sum();
    let mocap: Vec<Vec<Vec<(usize, Vec<f32>)>>> = if opts.ik_only {
        Vec::new()
    } else {
        opts.embeddings
            .iter()
            .map(|&e| {
                takes
                    .iter()
                    .map(|m| embed_windows(m, e, &ex, opts.hop).unwrap_or_default())
                    .collect()
            })
            .collect()
    };
    for &layout in &opts.layouts {
        let measures = [Measure::Observable, Measure::ParentFrame];
        let mut rest_errs = vec![Vec::new(), Vec::new()];
        for (condition, noisy) in [("clean", false), ("noisy", true)] {
            let mut errs = vec![Vec::new(), Vec::new()];
            let mut solved_takes: Vec<Motion> = Vec::new();
            for (i, m) in takes.iter().enumerate() {
                // Noisy keypoints also come from a camera at its own heading.
                let so = if noisy {
                    SynthOptions {
                        yaw_deg: ((opts.seed as usize + i) * 97 % 360) as f64,
                        ..SynthOptions::noisy(
                            layout,
                            opts.video_fps,
                            opts.seed.wrapping_add(i as u64),
                        )
                    }
                } else {
                    SynthOptions::clean(layout, opts.video_fps)
                };
                let truth = match m.resample(opts.video_fps) {
                    Ok(t) => t,
                    Err(e) => {
                        errors.push(e.to_string());
                        continue;
                    }
                };
                // The truth as the camera sees it: turned by its heading.
                let truth = turned(&truth, so.yaw_deg);
                let solve_opts = SolveOptions {
                    pelvis_share: opts.pelvis_share.unwrap_or(layout.pelvis_share()),
                    smooth_s: opts.smooth_s,
                    ..SolveOptions::new(layout)
                };
                let solved = synthesize(m, &so).and_then(|kp| solve(&m.name, &kp, &solve_opts));
                match solved {
                    Ok((s, _)) => {
                        let rest = truth
                            .with_data(truth.trans.clone(), vec![[0.0; 3]; truth.rotations.len()]);
                        for (i, &me) in measures.iter().enumerate() {
                            merge(&mut errs[i], joint_errors(layout, &s, &truth, me));
                            if !noisy {
                                merge(&mut rest_errs[i], joint_errors(layout, &rest, &truth, me));
                            }
                        }
                        solved_takes.push(s);
                    }
                    Err(e) => errors.push(format!("{layout} {condition}: {e}")),
                }
            }
            for (e, &me) in errs.into_iter().zip(&measures) {
                ik.extend(ik_rows(layout, condition, me, e));
            }
            if opts.ik_only || solved_takes.len() != takes.len() {
                continue;
            }
            for (ei, &e) in opts.embeddings.iter().enumerate() {
                let kps: Vec<Vec<(usize, Vec<f32>)>> = solved_takes
                    .iter()
                    .map(|m| embed_windows(m, e, &ex, opts.hop).unwrap_or_default())
                    .collect();
                for (direction, q, c) in [
                    ("keypoints->mocap", &kps, &mocap[ei]),
                    ("mocap->keypoints", &mocap[ei], &kps),
                ] {
                    let (r1, r10, same, n) = cross_search(q, c);
                    search.push(SearchRow {
                        layout: layout.name().into(),
                        condition: condition.into(),
                        direction: direction.into(),
                        embedding: e,
                        queries: n,
                        recall_at_1: r1,
                        recall_at_10: r10,
                        same_moment_at_1: same,
                        chance_at_1: 1.0 / takes.len().max(1) as f64,
                    });
                }
            }
        }
        for (e, &me) in rest_errs.into_iter().zip(&measures) {
            ik.extend(ik_rows(layout, "rest pose (baseline)", me, e));
        }
    }
    FootageEval {
        takes: takes.len(),
        frames,
        video_fps: opts.video_fps,
        pelvis_share: opts.pelvis_share,
        smooth_s: opts.smooth_s,
        ik,
        search,
        errors,
    }
}
