//! Parity: the exported graph in its runtime (tract or onnxruntime) against the trainer's own forward
//! pass, on one sequence, whole and token by token (incremental decoding).

use super::model::Gpt;
use crate::lm::runtime::{attention_bias, Kv, LmSession};
use crate::tokenize::vocab::Vocabulary;
use anyhow::Result;
use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::path::Path;

pub struct ParityReport {
    pub tokens: usize,
    /// Max |tract − candle| over all logits, whole-sequence step.
    pub whole: f32,
    /// The same, feeding the sequence in pieces through the cache.
    pub incremental: f32,
    /// Over class logits (whole step), 0 without heads.
    pub classes: f32,
    /// Largest |logit| seen, for scale.
    pub scale: f32,
}

impl std::fmt::Display for ParityReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "parity over {} tokens: max |runtime − trainer| = {:.2e} whole, {:.2e} incremental, {:.2e} class logits (logits up to {:.1})",
            self.tokens, self.whole, self.incremental, self.classes, self.scale
        )
    }
}

/// A random valid sequence: `<bos>`, the first value of each conditioning
/// kind, two frames of random value tokens, class tokens.
pub fn sample_sequence(
    model: &Gpt,
    vocab: &Vocabulary,
    seed: u64,
) -> (Vec<u32>, usize, usize, usize) {
    let cfg = &model.cfg;
    let mut rng = StdRng::seed_from_u64(seed);
    let mut toks = vec![vocab.bos()];
    for k in &cfg.cond_kinds {
        if let Some(v) = vocab.labels.get(k).and_then(|s| s.iter().next()) {
            toks.push(vocab.label_token(k, v).expect("known label"));
        }
    }
    let pl = toks.len();
    let frames = 2.min(cfg.max_frames);
    for _ in 0..frames {
        for s in 0..cfg.frame_len {
            let r = vocab.allowed(s);
            toks.push(if r.len() == 1 {
                r.start
            } else {
                rng.gen_range(r)
            });
        }
    }
    let nf = frames * cfg.frame_len;
    for (k, _) in &cfg.classes {
        toks.push(vocab.class_token(k).expect("class token"));
    }
    (toks, pl, nf, cfg.classes.len())
}

pub fn check(
    model: &Gpt,
    vocab: &Vocabulary,
    export_dir: &Path,
    seed: u64,
    engine: &crate::lm::engine::Engine,
) -> Result<ParityReport> {
    let cfg = &model.cfg;
    let (toks, pl, nf, nc) = sample_sequence(model, vocab, seed);
    let pos = cfg.positions(pl, nf, nc);
    let n = toks.len();
    let dev = Device::Cpu;
    let t = Tensor::from_vec(toks.clone(), (1, n), &dev)?;
    let pa = Tensor::from_vec(
        pos.iter().map(|p| p.a as u32).collect::<Vec<_>>(),
        (1, n),
        &dev,
    )?;
    let pb = Tensor::from_vec(
        pos.iter().map(|p| p.b as u32).collect::<Vec<_>>(),
        (1, n),
        &dev,
    )?;
    let bias = Tensor::from_vec(attention_bias(cfg.objective, 0, n), (1, 1, n, n), &dev)?;
    let (logits, cls, _) = model.forward(
        &t,
        &pa,
        (cfg.table_b() > 0).then_some(&pb),
        &bias,
        None,
        false,
    )?;
    let want: Vec<f32> = logits.flatten_all()?.to_vec1()?;
    let want_cls: Vec<Vec<f32>> = cls
        .iter()
        .map(|c| c.flatten_all().and_then(|x| x.to_vec1()))
        .collect::<candle_core::Result<_>>()?;

    let session = LmSession::load_with(export_dir, engine)?;
    let (whole, _) = session.step(&toks, &pos, Kv::empty(cfg))?;
    let diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max)
    };
    let d_whole = diff(&whole.logits, &want);
    let d_cls = whole
        .class_logits
        .iter()
        .zip(&want_cls)
        .map(|(a, b)| diff(a, b))
        .fold(0f32, f32::max);
    // Incremental: the prefix, then pieces of 1, 2, 3 … tokens.
    let mut got = Vec::with_capacity(want.len());
    let mut kv = Kv::empty(cfg);
    let mut i = 0;
    let mut piece = pl;
    while i < n {
        let j = (i + piece).min(n);
        let (out, next) = session.step(&toks[i..j], &pos[i..j], kv)?;
        got.extend_from_slice(&out.logits);
        kv = next;
        i = j;
        piece = piece % 5 + 1;
    }
    let d_inc = diff(&got, &want);
    let scale = want.iter().fold(0f32, |m, v| m.max(v.abs()));
    Ok(ParityReport {
        tokens: n,
        whole: d_whole,
        incremental: d_inc,
        classes: d_cls,
        scale,
    })
}
