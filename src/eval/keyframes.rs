//! `eval keyframes`: thesis 001 Tables 4.1–4.7 over a corpus.

use crate::features::smpl24_at_60;
use crate::keyframes::frames_per_measure;
use crate::keyframes::inbetween::BezierOffsets;
use crate::keyframes::metrics::{fid, geometric_features, kinetic_features, mse};
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::{Motion, MotionError};
use crate::service::keyframes::*;
use serde::Serialize;
use std::path::PathBuf;

#[derive(Clone, Debug, Serialize)]
pub struct EvalRow {
    pub select: Select,
    pub inbetween: String,
    pub keyframes_per_measure: usize,
    pub segments: usize,
    /// Mean over segments of Eq. 2.8, cm².
    pub mse_cm2: f64,
    pub fid_k: Option<f64>,
    pub fid_g: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct EvalKeyframes {
    pub rows: Vec<EvalRow>,
    pub clips: Vec<ClipInfo>,
    pub errors: Vec<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct ClipInfo {
    pub name: String,
    pub bpm: f64,
    pub tempo_known: bool,
    pub frames_per_measure: usize,
    pub measures: usize,
}

/// Thesis 001's protocol: every clip (SMPL-24, 60 fps) is cut into 4/4
/// measures at its tempo (`tempo_bpm` label, else `default_bpm`); each
/// measure is one sample whose first and last frames are keyframes. For 3,
/// 5 and 9 keyframes per measure and every (selection, in-between) pair:
/// mean MSE over measures, and FID_k / FID_g between the sets of original
/// and rebuilt measures. Bézier-average offsets for a clip are fitted on the
/// other clips' measures (leave one clip out) with the same selection.
pub fn eval_keyframes(
    files: &[PathBuf],
    default_bpm: f64,
    counts: &[usize],
) -> Result<EvalKeyframes, MotionError> {
    let mut clips = vec![];
    let mut infos = vec![];
    let mut errors = vec![];
    for f in files {
        let m = match read_path(f, &ReadOptions::default()).and_then(|l| smpl24_at_60(&l.motion)) {
            Ok(m) => m,
            Err(e) => {
                errors.push(e.to_string());
                continue;
            }
        };
        let (bpm, known) = match m
            .labels
            .get("tempo_bpm")
            .and_then(|t| t.parse::<f64>().ok())
        {
            Some(b) => (b, true),
            None => (default_bpm, false),
        };
        let fpm = frames_per_measure(bpm, m.fps).round() as usize;
        let measures: Vec<Motion> = (0..)
            .map(|k| k * fpm)
            .take_while(|&s| s + fpm < m.frames())
            .filter_map(|s| m.cut(s, s + fpm + 1).ok())
            .collect();
        infos.push(ClipInfo {
            name: m.name.clone(),
            bpm,
            tempo_known: known,
            frames_per_measure: fpm,
            measures: measures.len(),
        });
        clips.push((measures, bpm));
    }
    let total: usize = clips.iter().map(|c| c.0.len()).sum();
    if total == 0 {
        return Err(MotionError::invalid(
            "eval keyframes",
            "data",
            "no clip holds a whole measure",
        ));
    }
    let selects = [Select::Even, Select::Onset, Select::Dp];
    let mut rows = vec![];
    for &count in counts {
        for &sel in &selects {
            // Keyframes of every measure of every clip, once per selection.
            let keys: Vec<Vec<Vec<usize>>> = clips
                .iter()
                .map(|(ms, bpm)| {
                    ms.iter()
                        .map(|m| select_keyframes(m, sel, count, &Music::Bpm(*bpm)))
                        .collect::<Result<Vec<_>, _>>()
                })
                .collect::<Result<_, _>>()?;
            for how in ["slerp", "bezier", "bezier-avg", "catmull-rom"] {
                let mut mse_sum = 0.0;
                let (mut real_k, mut fake_k, mut real_g, mut fake_g) =
                    (vec![], vec![], vec![], vec![]);
                for (ci, (ms, _)) in clips.iter().enumerate() {
                    let method = match how {
                        "slerp" => Inbetween::Slerp,
                        "bezier" => Inbetween::Bezier,
                        "catmull-rom" => Inbetween::CatmullRom,
                        _ => {
                            let train: Vec<(&Motion, Vec<usize>)> = clips
                                .iter()
                                .enumerate()
                                .filter(|(cj, _)| *cj != ci)
                                .flat_map(|(cj, (ms2, _))| ms2.iter().zip(keys[cj].iter().cloned()))
                                .collect();
                            if train.is_empty() {
                                continue;
                            }
                            Inbetween::BezierAverage(BezierOffsets::fit(&train)?)
                        }
                    };
                    for (m, k) in ms.iter().zip(&keys[ci]) {
                        let r = rebuild(m, k, &method)?;
                        let (pa, pb) = (m.positions(), r.positions());
                        mse_sum += mse(&pa, &pb) * 1e4;
                        real_k.push(kinetic_features(&pa, 24, m.fps));
                        fake_k.push(kinetic_features(&pb, 24, m.fps));
                        real_g.push(geometric_features(&pa, 24));
                        fake_g.push(geometric_features(&pb, 24));
                    }
                }
                let segments = real_k.len();
                if segments == 0 {
                    continue;
                }
                rows.push(EvalRow {
                    select: sel,
                    inbetween: how.to_string(),
                    keyframes_per_measure: count,
                    segments,
                    mse_cm2: mse_sum / segments as f64,
                    fid_k: fid(&real_k, &fake_k),
                    fid_g: fid(&real_g, &fake_g),
                });
            }
        }
    }
    Ok(EvalKeyframes {
        rows,
        clips: infos,
        errors,
    })
}
