//! Codec metrics (thesis 000 §4.4.2, SPEC §4) and the settings of Tables
//! 4.1, 4.2 and Figure 4.5.
//!
//! - Average word length: symbols per word, the separator not counted
//!   (Eq. 4.5/4.6).
//! - Compression factor: bytes of the float32 input (`frames × channels ×
//!   4`) over bytes of the encoding, where every symbol and every separator
//!   costs `⌈log₂(alphabet + 1)⌉` bits (a fixed-length code).
//! - Seconds in 1,024 tokens: `1024 / (word length + 1) × frames per word /
//!   fps` — how much motion one context window holds.
//! - Geodesic error per joint (radians): the angle of `R_aᵀ R_b` between
//!   the original and the decoded rotation, mean and max over every joint of
//!   every frame.

use super::tile::{Reduction, TileCodec, TileSettings};
use super::{bits_per_symbol, wrap_joints, Codec, GeodesicError, Quantile, Series, Uniform};
use crate::motion::MotionError;
use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct CodecReport {
    pub codec: String,
    pub sequences: usize,
    pub frames: usize,
    pub words: usize,
    pub avg_word_length: f64,
    pub max_word_length: usize,
    pub compression_factor: f64,
    pub seconds_in_1024: f64,
    pub mean_error_rad: f64,
    pub p99_error_rad: f64,
    pub max_error_rad: f64,
}

/// Encode and decode every series with a codec and measure it.
pub fn evaluate(codec: &dyn Codec, data: &[&Series], fps: f64) -> Result<CodecReport, MotionError> {
    let (mut frames, mut words, mut symbols, mut max_len) = (0usize, 0usize, 0usize, 0usize);
    let mut err = GeodesicError::default();
    let mut values = 0usize;
    for s in data {
        let w = codec.encode(s)?;
        words += w.len();
        symbols += w.iter().map(|x| x.len()).sum::<usize>();
        max_len = max_len.max(w.iter().map(|x| x.len()).max().unwrap_or(0));
        let back = codec.decode(&w)?.truncated(s.frames());
        err.add(&wrap_joints(s), &back);
        frames += s.frames();
        values += s.frames() * s.channels;
    }
    if words == 0 {
        return Err(MotionError::invalid(
            "tokenize eval",
            "data",
            "no frames to encode",
        ));
    }
    let avg = symbols as f64 / words as f64;
    let bits = bits_per_symbol(codec.alphabet()) as f64;
    let encoded_bytes = (symbols + words) as f64 * bits / 8.0;
    Ok(CodecReport {
        codec: codec.describe(),
        sequences: data.len(),
        frames,
        words,
        avg_word_length: avg,
        max_word_length: max_len,
        compression_factor: (values * 4) as f64 / encoded_bytes,
        seconds_in_1024: 1024.0 / (avg + 1.0) * codec.frames_per_word() as f64 / fps,
        mean_error_rad: err.mean,
        p99_error_rad: err.quantile(0.99),
        max_error_rad: err.max,
    })
}

/// Table 4.1's settings: tiles of 15/30/60 frames × ICA/PCA, 10% kept, 24
/// components, 360 quantile bins.
pub fn table_4_1() -> Vec<TileSettings> {
    let mut out = vec![];
    for reduction in [Reduction::Ica, Reduction::Pca] {
        for tile in [15, 30, 60] {
            out.push(TileSettings {
                tile,
                reduction,
                components: 24,
                keep: 0.1,
                bins: 360,
            });
        }
    }
    out
}

/// Table 4.2's settings: tiles of 60 frames, PCA, (kept %, components).
pub fn table_4_2() -> Vec<TileSettings> {
    [
        (10, 15),
        (10, 24),
        (10, 33),
        (10, 42),
        (20, 15),
        (30, 15),
        (40, 15),
    ]
    .into_iter()
    .map(|(r, d)| TileSettings {
        tile: 60,
        reduction: Reduction::Pca,
        components: d,
        keep: r as f64 / 100.0,
        bins: 360,
    })
    .collect()
}

/// Figure 4.5's x axis: uniform bin counts.
pub const FIG_4_5_BINS: [usize; 12] = [8, 16, 32, 64, 90, 128, 180, 256, 360, 512, 720, 1024];

#[derive(Clone, Debug, Serialize)]
pub struct TokenizeTables {
    pub corpus: String,
    pub channels: usize,
    pub fps: f64,
    /// Frame codecs: uniform and quantile, 360 bins.
    pub frame_codecs: Vec<CodecReport>,
    pub table_4_1: Vec<CodecReport>,
    pub table_4_2: Vec<CodecReport>,
    /// Error versus uniform bins.
    pub figure_4_5: Vec<CodecReport>,
}

/// Every table for one corpus. Quantile bins, PCA/ICA and coefficient bins
/// are fitted on the same series they are measured on (a tokenizer is
/// fitted on its corpus).
pub fn tables(corpus: &str, data: &[&Series], fps: f64) -> Result<TokenizeTables, MotionError> {
    let channels = data.first().map(|s| s.channels).unwrap_or(0);
    let uniform = Uniform::new(360, channels)?;
    let quantile = Quantile::fit(data, 360)?;
    let frame_codecs = vec![
        evaluate(&uniform, data, fps)?,
        evaluate(&quantile, data, fps)?,
    ];
    let tile = |settings: Vec<TileSettings>| -> Result<Vec<CodecReport>, MotionError> {
        settings
            .into_iter()
            .filter(|s| s.components <= channels)
            .map(|s| evaluate(&TileCodec::fit(data, s)?, data, fps))
            .collect()
    };
    let figure_4_5 = FIG_4_5_BINS
        .iter()
        .map(|&b| evaluate(&Uniform::new(b, channels)?, data, fps))
        .collect::<Result<_, _>>()?;
    Ok(TokenizeTables {
        corpus: corpus.to_string(),
        channels,
        fps,
        frame_codecs,
        table_4_1: tile(table_4_1())?,
        table_4_2: tile(table_4_2())?,
        figure_4_5,
    })
}
