// The candle trainer's workload in burn: vocab 420, d 64, 2 pre-LN layers,
// 2 heads, ff 256, T 349, batch 8, causal; AdamW; tokens/s over 20 steps.
use burn::nn::transformer::{TransformerEncoder, TransformerEncoderConfig, TransformerEncoderInput};
use burn::nn::{Embedding, EmbeddingConfig, Linear, LinearConfig};
use burn::nn::attention::generate_autoregressive_mask;
use burn::nn::loss::CrossEntropyLossConfig;
use burn::optim::{AdamWConfig, GradientsParams, Optimizer};
use burn::prelude::*;
use std::time::Instant;

#[derive(Module, Debug)]
struct M { tok: Embedding, pos: Embedding, enc: TransformerEncoder, head: Linear }


fn main() {
    #[allow(deprecated)]
    let dev = Device::ndarray().autodiff();
    let (v, d, t, b) = (420usize, 64usize, 349usize, 8usize);
    let mut m = M {
        tok: EmbeddingConfig::new(v, d).init(&dev),
        pos: EmbeddingConfig::new(t, d).init(&dev),
        enc: TransformerEncoderConfig::new(d, 4 * d, 2, 2).with_norm_first(true).with_dropout(0.1).init(&dev),
        head: LinearConfig::new(d, v).init(&dev),
    };
    let mut opt = AdamWConfig::new().init();
    let ids: Vec<i64> = (0..b * t).map(|i| ((i * 7919) % 360) as i64).collect();
    let x = Tensor::<1, Int>::from_ints(ids.as_slice(), &dev).reshape([b, t]);
    let y = Tensor::<1, Int>::from_ints(ids.as_slice(), &dev).reshape([b * t]);
    let p = Tensor::<1, Int>::arange(0..t as i64, &dev).reshape([1, t]).repeat_dim(0, b);
    let mask = generate_autoregressive_mask(b, t, &dev);
    let steps = 20;
    let mut t0 = Instant::now();
    for s in 0..steps {
        if s == 2 { t0 = Instant::now(); }
        let h = m.tok.forward(x.clone()) + m.pos.forward(p.clone());
        let h = m.enc.forward(TransformerEncoderInput::new(h).mask_attn(mask.clone()));
        let logits = m.head.forward(h).reshape([b * t, v]);
        let loss = CrossEntropyLossConfig::new().init(&dev).forward(logits, y.clone());
        let g = GradientsParams::from_grads(loss.backward(), &m);
        m = opt.step(1e-3, m, g);
    }
    let secs = t0.elapsed().as_secs_f64();
    println!("burn 0.22 ndarray+autodiff: {:.0} tokens/s ({} steps of {} tokens in {:.2} s)", ((steps - 2) * b * t) as f64 / secs, steps - 2, b * t, secs);
}
