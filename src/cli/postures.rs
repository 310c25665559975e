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
}

pub fn run(a: PosturesArgs) -> Result<()> {
    let m =
        MotionModel::load(&a.model).with_context(|| format!("--model {}", a.model.display()))?;
    if !matches!(m, MotionModel::Frame(_)) {
        bail!("--model: postures are for the frame model (this folder holds the flat GPT)");
    }
    let vocab = m.vocabulary().clone();
    let sequences = super::exemplars::training_sequences(&vocab, &a.data)?;
    let p = Postures::fit(&sequences, &vocab, m.cond_kinds());
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
