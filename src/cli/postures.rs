//! `choreo postures`: writes a frame model's label postures
//! (`choreo::lm::posture`) from the training side of corpus folders.

use anyhow::{bail, Context, Result};
use choreo::lm::model::MotionModel;
use choreo::lm::posture::{Postures, FILE};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct PosturesArgs {
    /// The model folder; postures.json is written into it.
    #[arg(long, default_value = "models/default")]
    pub model: PathBuf,
    /// Corpus folders (repeatable), each split as the trainer splits it:
    /// only its training sequences count.
    #[arg(long, required = true)]
    pub data: Vec<PathBuf>,
    /// `KIND=K` (repeatable): fit K pose clusters per value of that label
    /// kind, so the pull follows the cluster a clip's previous frame sits
    /// in (a style's bow, walk and raised hand each keep their own pose)
    /// instead of one mean pose per label. The bundled file: style=8,
    /// content=8 (docs/RESULTS.md, "Session 32").
    #[arg(long, value_parser = parse_clusters)]
    pub clusters: Vec<(String, usize)>,
}

fn parse_clusters(s: &str) -> Result<(String, usize), String> {
    let (k, n) = s
        .split_once('=')
        .ok_or_else(|| format!("'{s}' is not KIND=K"))?;
    let n: usize = n
        .parse()
        .map_err(|_| format!("'{s}': K is not a whole number"))?;
    if !(2..=64).contains(&n) {
        return Err(format!("'{s}': K must be 2 to 64"));
    }
    Ok((k.to_string(), n))
}

pub fn run(a: PosturesArgs) -> Result<()> {
    let m =
        MotionModel::load(&a.model).with_context(|| format!("--model {}", a.model.display()))?;
    if !matches!(m, MotionModel::Frame(_)) {
        bail!("--model: postures are for the frame model (this folder holds the flat GPT)");
    }
    let vocab = m.vocabulary().clone();
    let sequences = super::exemplars::training_sequences(&vocab, &a.data)?;
    for (k, _) in &a.clusters {
        if !m.cond_kinds().contains(k) {
            bail!(
                "--clusters: '{k}' is not a label kind of this model ({})",
                m.cond_kinds().join(", ")
            );
        }
    }
    let clusters = a.clusters.iter().cloned().collect();
    let p = Postures::fit(&sequences, &vocab, m.cond_kinds(), &clusters);
    if p.labels.is_empty() {
        bail!("--data: no training sequence carries a label the model knows");
    }
    let path = a.model.join(FILE);
    std::fs::write(&path, serde_json::to_string(&p)?)
        .with_context(|| format!("writing {}", path.display()))?;
    for (k, vs) in &p.frames {
        eprintln!(
            "{k}: {} values ({} frames)",
            vs.len(),
            vs.values().sum::<usize>()
        );
    }
    println!("wrote {}", path.display());
    Ok(())
}
