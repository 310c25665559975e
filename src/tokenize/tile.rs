//! The JPEG-like tile codec (thesis 000 §4.4.1, SPEC §4).
//!
//! 1. Axis-angles are unwrapped along time, then reduced from `C` channels
//!    to `D` components by PCA, or by ICA (FastICA, symmetric, log-cosh, on
//!    the PCA-whitened data), fitted on the corpus.
//! 2. The sequence is cut into tiles of `L` frames (the last tile is padded
//!    by repeating its final frame); each component gets an orthonormal
//!    DCT-II over the tile.
//! 3. The largest `R`·`D`·`L` coefficients (by magnitude) of the tile are
//!    kept, the rest set to zero.
//! 4. Kept coefficients are binned with per-component quantile bins fitted
//!    on the kept coefficients of the corpus; the zeros, read in
//!    component-major, low-to-high-frequency order, are run-length coded:
//!    one symbol `bins + n − 1` stands for a run of `n ≤ L` zeros.
//!
//! A word is one tile: its symbols in that order.

use super::{
    bad_symbol, check_channels, quantile_bins, quantile_encode, unwrap_joints, Codec, Series,
};
use crate::features::interpolate::Dct;
use crate::features::pca::{jacobi_eigen, matmul};
use crate::motion::MotionError;
use rand::{Rng, SeedableRng};

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reduction {
    Pca,
    Ica,
}

impl Reduction {
    pub fn name(self) -> &'static str {
        match self {
            Reduction::Pca => "pca",
            Reduction::Ica => "ica",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TileSettings {
    /// Frames a tile spans (`L`).
    pub tile: usize,
    pub reduction: Reduction,
    /// Components kept (`D`).
    pub components: usize,
    /// Fraction of a tile's `D·L` DCT coefficients kept (`R`).
    pub keep: f64,
    /// Quantile bins for the kept coefficients.
    pub bins: usize,
}

impl TileSettings {
    pub fn validate(&self, channels: usize) -> Result<(), MotionError> {
        let bad =
            |field: &str, reason: String| Err(MotionError::invalid("tile codec", field, reason));
        if self.tile < 2 || self.tile > 4096 {
            return bad("tile", format!("{} frames; need 2..=4096", self.tile));
        }
        if self.components == 0 || self.components > channels {
            return bad(
                "components",
                format!(
                    "{}; need 1..={channels} (the channel count)",
                    self.components
                ),
            );
        }
        if !(self.keep > 0.0 && self.keep <= 1.0) {
            return bad("keep", format!("{}; need a fraction in (0, 1]", self.keep));
        }
        if self.bins < 2 || self.bins > 65_536 {
            return bad("bins", format!("{}; need 2..=65536", self.bins));
        }
        Ok(())
    }
    fn kept(&self) -> usize {
        ((self.keep * (self.tile * self.components) as f64).round() as usize).max(1)
    }
}

pub struct TileCodec {
    pub settings: TileSettings,
    channels: usize,
    mean: Vec<f64>,
    /// `[D][C]`: components = to_comp · (x − mean).
    to_comp: Vec<f64>,
    /// `[C][D]`: x = mean + from_comp · components.
    from_comp: Vec<f64>,
    edges: Vec<Vec<f64>>,
    centres: Vec<Vec<f64>>,
    dct: Dct,
}

impl TileCodec {
    /// Fit the reduction and the coefficient bins on a corpus.
    pub fn fit(data: &[&Series], settings: TileSettings) -> Result<TileCodec, MotionError> {
        let c = data
            .first()
            .map(|s| s.channels)
            .ok_or_else(|| MotionError::invalid("tile codec", "data", "no series to fit on"))?;
        settings.validate(c)?;
        let d = settings.components;
        let unwrapped: Vec<Series> = data
            .iter()
            .map(|s| {
                let mut u = (*s).clone();
                unwrap_joints(&mut u);
                u
            })
            .collect();
        let n: usize = unwrapped.iter().map(|s| s.frames()).sum();
        if n < 2 || unwrapped.iter().any(|s| s.channels != c) {
            return Err(MotionError::invalid(
                "tile codec",
                "data",
                "need at least 2 frames, all series with the same channel count",
            ));
        }
        let mut mean = vec![0.0; c];
        for s in &unwrapped {
            for t in 0..s.frames() {
                s.row(t)
                    .iter()
                    .zip(mean.iter_mut())
                    .for_each(|(v, m)| *m += v);
            }
        }
        mean.iter_mut().for_each(|m| *m /= n as f64);
        let mut cov = vec![0.0; c * c];
        let mut xc = vec![0.0; c];
        for s in &unwrapped {
            for t in 0..s.frames() {
                for i in 0..c {
                    xc[i] = s.row(t)[i] - mean[i];
                }
                for i in 0..c {
                    let xi = xc[i];
                    let row = &mut cov[i * c..(i + 1) * c];
                    for j in i..c {
                        row[j] += xi * xc[j];
                    }
                }
            }
        }
        for i in 0..c {
            for j in i..c {
                let v = cov[i * c + j] / (n - 1) as f64;
                cov[i * c + j] = v;
                cov[j * c + i] = v;
            }
        }
        let (vals, vecs) = jacobi_eigen(cov, c);
        let mut order: Vec<usize> = (0..c).collect();
        order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]));
        // W: [C][D], columns the leading eigenvectors.
        let w: Vec<f64> = (0..c)
            .flat_map(|i| order[..d].iter().map(move |&k| (i, k)))
            .map(|(i, k)| vecs[i * c + k])
            .collect();
        let (to_comp, from_comp) = match settings.reduction {
            Reduction::Pca => {
                let to: Vec<f64> = (0..d)
                    .flat_map(|k| (0..c).map(move |i| (i, k)))
                    .map(|(i, k)| w[i * d + k])
                    .collect();
                (to, w.clone())
            }
            Reduction::Ica => {
                let floor = vals[order[0]].max(1e-300) * 1e-12;
                let sd: Vec<f64> = order[..d]
                    .iter()
                    .map(|&k| vals[k].max(floor).sqrt())
                    .collect();
                // Whitened samples z = Λ^{-½} Wᵀ (x − μ), a seeded subsample.
                let mut rng = rand::rngs::StdRng::seed_from_u64(0x1ca);
                let take = n.min(20_000);
                let all: Vec<(usize, usize)> = unwrapped
                    .iter()
                    .enumerate()
                    .flat_map(|(i, s)| (0..s.frames()).map(move |t| (i, t)))
                    .collect();
                let mut z = Vec::with_capacity(take * d);
                for _ in 0..take {
                    let (i, t) = all[rng.gen_range(0..all.len())];
                    let x = unwrapped[i].row(t);
                    for k in 0..d {
                        let p: f64 = (0..c).map(|j| w[j * d + k] * (x[j] - mean[j])).sum();
                        z.push(p / sd[k]);
                    }
                }
                let r = fast_ica(&z, d, &mut rng);
                // to = R Λ^{-½} Wᵀ, from = W Λ^{½} Rᵀ.
                let mut to = vec![0.0; d * c];
                let mut from = vec![0.0; c * d];
                for a in 0..d {
                    for j in 0..c {
                        let mut s_to = 0.0;
                        for k in 0..d {
                            s_to += r[a * d + k] / sd[k] * w[j * d + k];
                        }
                        to[a * c + j] = s_to;
                        let mut s_from = 0.0;
                        for k in 0..d {
                            s_from += w[j * d + k] * sd[k] * r[a * d + k];
                        }
                        from[j * d + a] = s_from;
                    }
                }
                (to, from)
            }
        };
        let mut codec = TileCodec {
            settings,
            channels: c,
            mean,
            to_comp,
            from_comp,
            edges: vec![],
            centres: vec![],
            dct: Dct::new(settings.tile),
        };
        // Bins for the kept coefficients, per component.
        let mut kept: Vec<Vec<f64>> = vec![vec![]; d];
        for s in &unwrapped {
            for coef in codec.tiles(s) {
                let mask = codec.keep_mask(&coef);
                for (p, &v) in coef.iter().enumerate() {
                    if mask[p] {
                        kept[p / settings.tile].push(v);
                    }
                }
            }
        }
        for v in kept {
            let (e, m) = quantile_bins(v, settings.bins);
            codec.edges.push(e);
            codec.centres.push(m);
        }
        Ok(codec)
    }

    /// Each tile's DCT coefficients, `[D][L]` row-major, of an unwrapped
    /// series.
    fn tiles(&self, s: &Series) -> Vec<Vec<f64>> {
        let (l, d, c) = (self.settings.tile, self.settings.components, self.channels);
        let frames = s.frames();
        let n_tiles = frames.div_ceil(l);
        let mut out = Vec::with_capacity(n_tiles);
        let mut xc = vec![0.0; c];
        for tile in 0..n_tiles {
            let mut coef = vec![0.0; d * l];
            for f in 0..l {
                let t = (tile * l + f).min(frames - 1);
                for j in 0..c {
                    xc[j] = s.row(t)[j] - self.mean[j];
                }
                for k in 0..d {
                    let row = &self.to_comp[k * c..(k + 1) * c];
                    coef[k * l + f] = row.iter().zip(&xc).map(|(a, b)| a * b).sum();
                }
            }
            for k in 0..d {
                self.dct.forward(&mut coef[k * l..(k + 1) * l]);
            }
            out.push(coef);
        }
        out
    }

    /// Which coefficients of a tile are kept: the largest `R·D·L` by
    /// magnitude (ties broken by position, low first).
    fn keep_mask(&self, coef: &[f64]) -> Vec<bool> {
        let k = self.settings.kept().min(coef.len());
        let mut idx: Vec<usize> = (0..coef.len()).collect();
        idx.select_nth_unstable_by(k - 1, |&a, &b| {
            coef[b].abs().total_cmp(&coef[a].abs()).then(a.cmp(&b))
        });
        let mut mask = vec![false; coef.len()];
        idx[..k].iter().for_each(|&i| mask[i] = true);
        mask
    }
}

/// Symmetric FastICA with the log-cosh contrast on whitened samples
/// (`[n][d]` row-major). Returns the orthonormal unmixing rotation `[d][d]`.
fn fast_ica(z: &[f64], d: usize, rng: &mut impl Rng) -> Vec<f64> {
    let n = z.len() / d;
    let mut w: Vec<f64> = (0..d * d).map(|_| rng.gen_range(-1.0..1.0)).collect();
    w = sym_decorrelate(&w, d);
    for _ in 0..200 {
        let mut next = vec![0.0; d * d];
        let mut gp = vec![0.0; d];
        for s in 0..n {
            let x = &z[s * d..(s + 1) * d];
            for a in 0..d {
                let u: f64 = (0..d).map(|k| w[a * d + k] * x[k]).sum();
                let g = u.tanh();
                gp[a] += 1.0 - g * g;
                for k in 0..d {
                    next[a * d + k] += g * x[k];
                }
            }
        }
        for a in 0..d {
            for k in 0..d {
                next[a * d + k] = next[a * d + k] / n as f64 - gp[a] / n as f64 * w[a * d + k];
            }
        }
        let next = sym_decorrelate(&next, d);
        let change = (0..d)
            .map(|a| {
                let dot: f64 = (0..d).map(|k| next[a * d + k] * w[a * d + k]).sum();
                (dot.abs() - 1.0).abs()
            })
            .fold(0.0, f64::max);
        w = next;
        if change < 1e-6 {
            break;
        }
    }
    w
}

/// `(W Wᵀ)^{-½} W`.
fn sym_decorrelate(w: &[f64], d: usize) -> Vec<f64> {
    let mut g = vec![0.0; d * d];
    for a in 0..d {
        for b in 0..d {
            g[a * d + b] = (0..d).map(|k| w[a * d + k] * w[b * d + k]).sum();
        }
    }
    let (vals, vecs) = jacobi_eigen(g, d);
    // M = V diag(1/√λ) Vᵀ
    let mut m = vec![0.0; d * d];
    for a in 0..d {
        for b in 0..d {
            m[a * d + b] = (0..d)
                .map(|k| vecs[a * d + k] * vecs[b * d + k] / vals[k].max(1e-300).sqrt())
                .sum();
        }
    }
    matmul(&m, w, d)
}

impl Codec for TileCodec {
    fn describe(&self) -> String {
        let s = &self.settings;
        format!(
            "tile-{}-{}{}-keep{}%-q{}",
            s.tile,
            s.reduction.name(),
            s.components,
            (s.keep * 100.0).round(),
            s.bins
        )
    }
    fn alphabet(&self) -> usize {
        self.settings.bins + self.settings.tile
    }
    fn frames_per_word(&self) -> usize {
        self.settings.tile
    }
    fn channels(&self) -> usize {
        self.channels
    }
    fn encode(&self, x: &Series) -> Result<Vec<Vec<u32>>, MotionError> {
        check_channels(self, x)?;
        if x.frames() == 0 {
            return Ok(vec![]);
        }
        let (l, bins) = (self.settings.tile, self.settings.bins as u32);
        let mut u = x.clone();
        unwrap_joints(&mut u);
        Ok(self
            .tiles(&u)
            .into_iter()
            .map(|coef| {
                let mask = self.keep_mask(&coef);
                let mut word = Vec::new();
                let mut run = 0u32;
                for (p, &v) in coef.iter().enumerate() {
                    if mask[p] {
                        if run > 0 {
                            word.push(bins + run - 1);
                            run = 0;
                        }
                        word.push(quantile_encode(&self.edges[p / l], v));
                    } else {
                        run += 1;
                        if run as usize == l {
                            word.push(bins + run - 1);
                            run = 0;
                        }
                    }
                }
                if run > 0 {
                    word.push(bins + run - 1);
                }
                word
            })
            .collect())
    }
    fn decode(&self, words: &[Vec<u32>]) -> Result<Series, MotionError> {
        let (l, d, c) = (self.settings.tile, self.settings.components, self.channels);
        let bins = self.settings.bins as u32;
        let mut data = Vec::with_capacity(words.len() * l * c);
        for (wi, word) in words.iter().enumerate() {
            let mut coef = vec![0.0; d * l];
            let mut p = 0usize;
            for (si, &s) in word.iter().enumerate() {
                if s as usize >= self.alphabet() {
                    return Err(bad_symbol(self, wi, si, s));
                }
                let span = if s < bins { 1 } else { (s - bins + 1) as usize };
                if p + span > d * l {
                    return Err(MotionError::invalid(
                        "tokens",
                        format!("word {wi}, symbol {si}"),
                        format!("runs past the tile's {} coefficients", d * l),
                    ));
                }
                if s < bins {
                    coef[p] = self.centres[p / l][s as usize];
                }
                p += span;
            }
            if p != d * l {
                return Err(MotionError::invalid(
                    "tokens",
                    format!("word {wi}"),
                    format!("covers {p} coefficients, a tile has {}", d * l),
                ));
            }
            for k in 0..d {
                self.dct.inverse(&mut coef[k * l..(k + 1) * l]);
            }
            for f in 0..l {
                for j in 0..c {
                    let row = &self.from_comp[j * d..(j + 1) * d];
                    let v: f64 =
                        self.mean[j] + (0..d).map(|k| row[k] * coef[k * l + f]).sum::<f64>();
                    data.push(v);
                }
            }
        }
        Series::new(c, data)
    }
}

#[cfg(test)]
mod tests;
