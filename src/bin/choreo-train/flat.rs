//! The thesis's flat GPT: `choreo-train train` turns its flags into a
//! [`tr::flat_run::FlatRun`]; the loop is the library's.

use super::*;

pub(crate) fn train(a: TrainArgs, engine: &choreo::lm::engine::Engine) -> Result<()> {
    let run = tr::flat_run::FlatRun {
        out: a.out.clone(),
        init: a.init.clone(),
        resume: a.resume,
        d_model: a.d_model,
        layers: a.layers,
        heads: a.heads,
        frames: a.frames,
        positions: match a.positions {
            Positions::Absolute => PosScheme::Absolute,
            Positions::FrameSlot => PosScheme::FrameSlot,
        },
        objective: match a.objective {
            Obj::Causal => Objective::Causal,
            Obj::Masked => Objective::Masked,
        },
        joints: a.joints,
        cond: a.cond.clone(),
        classify: a.classify.clone(),
        steps: a.steps,
        batch: a.batch,
        lr: a.lr,
        dropout: a.dropout,
        eval_every: a.eval_every,
        seed: a.seed,
        max_seconds: a.max_seconds,
        corpus_weights: super::frame::parse_corpus_weights(&a.corpus_weight)?,
        export: a.export,
        lr_sweep: a.lr_sweep,
    };
    let report = tr::flat_run::train(
        &run,
        |known, kinds| load_corpus(&a.data, known, kinds, a.joints == 24, a.fps),
        engine,
    )?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
