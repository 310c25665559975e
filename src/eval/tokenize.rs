//! `choreo eval tokenize`: the tokenizer tables (thesis 000 Tables 4.1,
//! 4.2, Figure 4.5) on real corpora.

use crate::features::smpl24_at_60;
use crate::motion::io::{read_path, ReadOptions};
use crate::motion::Motion;
use crate::plot::{Chart, Line, PALETTE};
use crate::tokenize::eval::{evaluate, tables, CodecReport, TokenizeTables};
use crate::tokenize::vocab::Vocabulary;
use crate::tokenize::{Quantile, Series, Uniform};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Serialize)]
pub struct CorpusTokenize {
    #[serde(flatten)]
    pub tables: TokenizeTables,
    /// The language model's frame layout: SMPL-13 at 20 fps (39 angle
    /// channels), uniform and quantile 360 — the angles alone, as Eq. 4.5
    /// counts them (the model adds 3 root tokens and a separator a frame).
    pub model_layout: Vec<CodecReport>,
    pub files: usize,
    pub errors: Vec<String>,
}

/// A motion's rotations as a series (`[frames][3·joints]`).
pub fn rotation_series(m: &Motion) -> Series {
    let data = m.rotations.iter().flat_map(|r| r.iter().copied()).collect();
    Series::new(3 * m.joints(), data).expect("a validated motion has finite rotations")
}

/// Every table for the files under one path.
pub fn eval_corpus(path: &Path) -> Result<CorpusTokenize, crate::motion::MotionError> {
    let files = crate::search::ingest::collect_files(&[path.to_path_buf()]);
    let vocab = Vocabulary::new(BTreeMap::new());
    let (mut s72, mut s39, mut errors) = (vec![], vec![], vec![]);
    for f in &files {
        let m = match read_path(f, &ReadOptions::default()) {
            Ok(l) => l.motion,
            Err(e) => {
                errors.push(e.to_string());
                continue;
            }
        };
        match smpl24_at_60(&m).and_then(|a| Ok((a, vocab.prepare(&m)?))) {
            Ok((a, b)) => {
                s72.push(rotation_series(&a));
                s39.push(rotation_series(&b));
            }
            Err(e) => errors.push(e.to_string()),
        }
    }
    let refs72: Vec<&Series> = s72.iter().collect();
    let refs39: Vec<&Series> = s39.iter().collect();
    let tables = tables(&path.display().to_string(), &refs72, 60.0)?;
    let model_layout = vec![
        evaluate(&Uniform::new(360, 39)?, &refs39, vocab.fps)?,
        evaluate(&Quantile::fit(&refs39, 360)?, &refs39, vocab.fps)?,
    ];
    Ok(CorpusTokenize {
        tables,
        model_layout,
        files: files.len(),
        errors,
    })
}

/// Figure 4.5 as a chart: mean and max geodesic error (degrees) against the
/// number of uniform bins, one pair of lines per corpus.
pub fn figure_4_5(corpora: &[CorpusTokenize]) -> Chart {
    let mut lines = vec![];
    for (i, c) in corpora.iter().enumerate() {
        // The last two path components name the corpus (aistpp/motions).
        let p = PathBuf::from(&c.tables.corpus);
        let parts: Vec<String> = p
            .components()
            .filter_map(|s| match s {
                std::path::Component::Normal(x) => Some(x.to_string_lossy().to_string()),
                _ => None,
            })
            .collect();
        let name = parts[parts.len().saturating_sub(2)..].join("/");
        let pts = |f: fn(&CodecReport) -> f64| -> Vec<(f64, f64)> {
            c.tables
                .figure_4_5
                .iter()
                .map(|r| (bins_of(&r.codec), f(r).to_degrees()))
                .collect()
        };
        lines.push(Line {
            name: format!("{name} mean"),
            points: pts(|r| r.mean_error_rad),
            color: PALETTE[(2 * i) % 6],
        });
        lines.push(Line {
            name: format!("{name} max"),
            points: pts(|r| r.max_error_rad),
            color: PALETTE[(2 * i + 1) % 6],
        });
    }
    Chart {
        title: "Geodesic error vs uniform bins".into(),
        x_label: "bins per axis-angle component".into(),
        y_label: "error per joint (deg)".into(),
        log_x: true,
        log_y: true,
        lines,
    }
}

fn bins_of(codec: &str) -> f64 {
    codec
        .rsplit('-')
        .next()
        .and_then(|b| b.parse().ok())
        .unwrap_or(f64::NAN)
}
