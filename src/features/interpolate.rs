//! Spectral interpolation ("style transfer" for motion, thesis 000 §3.5–3.7,
//! SPEC §3) and low-pass filtering. Pure.
//!
//! Both clips are brought to SMPL-24 at 60 fps ([`super::channels72`]) and cut
//! to the shorter length `L`. The output starts as the input's channel matrix
//! and moves, by Adam, to minimise the mean squared difference between its
//! features and the target's inside a frequency band:
//!
//! - `Dct`: orthonormal DCT-II along time of each channel (length `L`). The
//!   band `[lo, hi)` is given in coefficients of a 128-frame window (the
//!   thesis's unit: `0:8` = 0–1.875 Hz at 60 fps) and scaled to `L`. The DCT
//!   is linear and orthonormal, so the gradient is exact:
//!   `2/n · IDCT(mask ⊙ (Dx − Dy))`.
//! - `Stft`: magnitudes of the Hann-16/hop-8 STFT over the whole clip, bins
//!   whose frequency lies in the band; gradient derived by hand
//!   (`∂|X|/∂x = Re(conj(X)·∂X/∂x)/|X|`).
//! - `Pca`: 16-component PCA projections of each channel's non-overlapping
//!   128-frame windows (basis fitted on both clips); components `[lo, hi)`
//!   clamped to 16; gradient `2/n · Pᵀ(Px − Py)`.
//!
//! Adam runs on each channel's orthonormal DCT coefficients (the same
//! optimum, since the DCT is orthonormal), so a DCT-band objective changes
//! nothing outside its band. Both clips' axis-angle trajectories are first
//! made continuous (each frame takes the equivalent vector, `v·(1 ± 2π/|v|)`,
//! nearest the previous frame), so smooth changes stay smooth rotations; the
//! output is wrapped back to norms ≤ π.

use super::{window, window_starts, Embedding, Pca, CHANNELS, COEFFS, FEATURE_FPS, WINDOW};
use crate::motion::rotation::{unwrap_axis_angle_rows, wrap_axis_angle_rows};
use crate::motion::MotionError;
use rustdct::DctPlanner;
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;
use serde::Serialize;

/// A channel matrix: `[frames][72]`, f64 for the optimiser.
pub type Channels = Vec<[f64; CHANNELS]>;

#[derive(Clone, Debug)]
pub struct InterpolateOptions {
    pub objective: Embedding,
    /// Band in 128-frame DCT coefficients (or PCA components), `[lo, hi)`.
    pub band: (usize, usize),
    pub steps: usize,
    pub learning_rate: f64,
}

impl Default for InterpolateOptions {
    fn default() -> Self {
        InterpolateOptions {
            objective: Embedding::Dct,
            band: (0, 8),
            steps: 300,
            learning_rate: 0.02,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct InterpolateResult {
    #[serde(skip)]
    pub output: Channels,
    /// Loss after each step (the first entry is before any step).
    pub loss: Vec<f64>,
    pub steps: usize,
    pub frames: usize,
}

pub fn to_f64(ch: &[[f32; CHANNELS]]) -> Channels {
    ch.iter()
        .map(|r| std::array::from_fn(|c| r[c] as f64))
        .collect()
}

/// Orthonormal DCT-II / DCT-III (its inverse) along time, per channel.
pub(crate) struct Dct {
    fwd: std::sync::Arc<dyn rustdct::TransformType2And3<f64>>,
    n: usize,
}

impl Dct {
    pub(crate) fn new(n: usize) -> Self {
        Dct {
            fwd: DctPlanner::new().plan_dct2(n),
            n,
        }
    }
    pub(crate) fn forward(&self, x: &mut [f64]) {
        self.fwd.process_dct2(x);
        let (s0, sk) = ((1.0 / self.n as f64).sqrt(), (2.0 / self.n as f64).sqrt());
        x[0] *= s0;
        x[1..].iter_mut().for_each(|v| *v *= sk);
    }
    pub(crate) fn inverse(&self, x: &mut [f64]) {
        // rustdct's DCT-III is y_n = x_0/2 + Σ_{k≥1} x_k cos(πk(2n+1)/2N), so
        // the orthonormal inverse weighs x_0 by 2/√N and the rest by √(2/N).
        let (s0, sk) = (
            2.0 * (1.0 / self.n as f64).sqrt(),
            (2.0 / self.n as f64).sqrt(),
        );
        x[0] *= s0;
        x[1..].iter_mut().for_each(|v| *v *= sk);
        self.fwd.process_dct3(x);
    }
}

/// Apply `f` to every channel's time series (in place on a copy).
fn map_columns(x: &[[f64; CHANNELS]], f: impl Fn(&mut [f64])) -> Channels {
    let mut out = x.to_vec();
    for c in 0..CHANNELS {
        let mut col = column(x, c);
        f(&mut col);
        for (t, v) in col.into_iter().enumerate() {
            out[t][c] = v;
        }
    }
    out
}

fn column(x: &[[f64; CHANNELS]], c: usize) -> Vec<f64> {
    x.iter().map(|r| r[c]).collect()
}

/// Zero every DCT coefficient at or above `cutoff` (in 128-frame units,
/// scaled to the clip length) along time, per channel.
pub fn lowpass(x: &Channels, cutoff: usize) -> Result<Channels, MotionError> {
    let n = x.len();
    if n < 2 {
        return Err(MotionError::invalid(
            "lowpass",
            "frames",
            "needs at least 2 frames",
        ));
    }
    if cutoff == 0 || cutoff > WINDOW {
        return Err(MotionError::invalid(
            "lowpass",
            "cutoff",
            format!("{cutoff} is not in 1..={WINDOW}"),
        ));
    }
    let k = scaled(cutoff, n);
    let dct = Dct::new(n);
    let mut out = map_columns(x, |col| {
        dct.forward(col);
        col[k.min(n)..].iter_mut().for_each(|v| *v = 0.0);
        dct.inverse(col);
    });
    wrap_all(&mut out);
    Ok(out)
}

/// A coefficient index of a 128-frame DCT as the same frequency for length n.
fn scaled(k: usize, n: usize) -> usize {
    ((k as f64) * n as f64 / WINDOW as f64).round() as usize
}

/// Make each joint's axis-angle continuous over time (see
/// [`unwrap_axis_angle_rows`]).
pub fn unwrap_axis_angle(x: &mut Channels) {
    unwrap_axis_angle_rows(x.as_flattened_mut(), CHANNELS);
}

fn wrap_all(x: &mut Channels) {
    wrap_axis_angle_rows(x.as_flattened_mut(), CHANNELS);
}

/// An objective: loss and gradient with respect to the channel matrix.
trait Objective {
    fn loss_grad(&self, x: &Channels, grad: &mut Channels) -> f64;
}

struct DctObjective {
    dct: Dct,
    lo: usize,
    hi: usize,
    /// Target coefficients in the band, `[channel][k - lo]`.
    target: Vec<Vec<f64>>,
}

impl Objective for DctObjective {
    fn loss_grad(&self, x: &Channels, grad: &mut Channels) -> f64 {
        let n = x.len();
        let count = (CHANNELS * (self.hi - self.lo)) as f64;
        let mut loss = 0.0;
        for c in 0..CHANNELS {
            let mut col = column(x, c);
            self.dct.forward(&mut col);
            let mut r = vec![0.0; n];
            for k in self.lo..self.hi {
                let d = col[k] - self.target[c][k - self.lo];
                loss += d * d;
                r[k] = 2.0 * d / count;
            }
            self.dct.inverse(&mut r);
            for t in 0..n {
                grad[t][c] = r[t];
            }
        }
        loss / count
    }
}

struct StftObjective {
    win: Vec<f64>,
    hop: usize,
    bins: std::ops::Range<usize>,
    /// Target magnitudes `[channel][frame][bin]`.
    target: Vec<Vec<Vec<f64>>>,
    fft: std::sync::Arc<dyn rustfft::Fft<f64>>,
}

impl StftObjective {
    fn frames(&self, n: usize) -> usize {
        1 + (n - self.win.len()) / self.hop
    }
    fn spectrum(&self, col: &[f64], f: usize) -> Vec<Complex<f64>> {
        let n = self.win.len();
        let mut buf: Vec<Complex<f64>> = (0..n)
            .map(|k| Complex::new(col[f * self.hop + k] * self.win[k], 0.0))
            .collect();
        self.fft.process(&mut buf);
        buf
    }
    fn magnitudes(&self, col: &[f64]) -> Vec<Vec<f64>> {
        (0..self.frames(col.len()))
            .map(|f| {
                self.spectrum(col, f)[self.bins.clone()]
                    .iter()
                    .map(|z| z.norm())
                    .collect()
            })
            .collect()
    }
}

impl Objective for StftObjective {
    fn loss_grad(&self, x: &Channels, grad: &mut Channels) -> f64 {
        let n = x.len();
        let m = self.win.len();
        let frames = self.frames(n);
        let count = (CHANNELS * frames * self.bins.len()) as f64;
        let mut loss = 0.0;
        grad.iter_mut().for_each(|r| *r = [0.0; CHANNELS]);
        for c in 0..CHANNELS {
            let col = column(x, c);
            for f in 0..frames {
                let spec = self.spectrum(&col, f);
                for (bi, k) in self.bins.clone().enumerate() {
                    let z = spec[k];
                    let mag = z.norm();
                    let d = mag - self.target[c][f][bi];
                    loss += d * d;
                    if mag < 1e-12 {
                        continue; // |X| is not differentiable at 0; its subgradient 0 is used
                    }
                    let coef = 2.0 * d / count / mag;
                    // dX_k/dx_{s+t} = w_t e^{-2πi k t / m}; d|X|/dx = Re(conj(X) dX/dx)/|X|.
                    for t in 0..m {
                        let ang = -2.0 * std::f64::consts::PI * (k * t) as f64 / m as f64;
                        let dre = self.win[t] * ang.cos();
                        let dim = self.win[t] * ang.sin();
                        grad[f * self.hop + t][c] += coef * (z.re * dre + z.im * dim);
                    }
                }
            }
        }
        loss / count
    }
}

struct PcaObjective {
    pca: Pca,
    lo: usize,
    hi: usize,
    starts: Vec<usize>,
    /// Target projections per window `[window][channel][component]`.
    target: Vec<Vec<Vec<f64>>>,
}

impl PcaObjective {
    fn project(&self, x: &Channels, s: usize, c: usize) -> Vec<f64> {
        (self.lo..self.hi)
            .map(|k| {
                let comp = &self.pca.components[k * WINDOW..(k + 1) * WINDOW];
                (0..WINDOW)
                    .map(|t| comp[t] as f64 * (x[s + t][c] - self.pca.mean[t] as f64))
                    .sum()
            })
            .collect()
    }
}

impl Objective for PcaObjective {
    fn loss_grad(&self, x: &Channels, grad: &mut Channels) -> f64 {
        let count = (self.starts.len() * CHANNELS * (self.hi - self.lo)) as f64;
        let mut loss = 0.0;
        grad.iter_mut().for_each(|r| *r = [0.0; CHANNELS]);
        for (wi, &s) in self.starts.iter().enumerate() {
            for c in 0..CHANNELS {
                let p = self.project(x, s, c);
                for (ki, k) in (self.lo..self.hi).enumerate() {
                    let d = p[ki] - self.target[wi][c][ki];
                    loss += d * d;
                    let comp = &self.pca.components[k * WINDOW..(k + 1) * WINDOW];
                    for t in 0..WINDOW {
                        grad[s + t][c] += 2.0 * d / count * comp[t] as f64;
                    }
                }
            }
        }
        loss / count
    }
}

fn f32_rows(x: &Channels) -> Vec<[f32; CHANNELS]> {
    x.iter()
        .map(|r| std::array::from_fn(|c| r[c] as f32))
        .collect()
}

/// Move `input` toward `target` in the band by Adam. Both are `[frames][72]`
/// at 60 fps; the longer is cut to the shorter.
pub fn interpolate(
    input: &Channels,
    target: &Channels,
    opts: &InterpolateOptions,
) -> Result<InterpolateResult, MotionError> {
    let n = input.len().min(target.len());
    let (lo, hi) = opts.band;
    if n < WINDOW {
        return Err(MotionError::invalid(
            "interpolate",
            "frames",
            format!("clips need at least {WINDOW} frames at 60 fps, the shorter has {n}"),
        ));
    }
    if lo >= hi || hi > WINDOW {
        return Err(MotionError::invalid(
            "interpolate",
            "band",
            format!("{lo}:{hi} is not a band inside 0:{WINDOW}"),
        ));
    }
    if opts.steps == 0 || opts.steps > 100_000 {
        return Err(MotionError::invalid(
            "interpolate",
            "steps",
            format!("{} is not in 1..=100000", opts.steps),
        ));
    }
    if !(opts.learning_rate.is_finite() && opts.learning_rate > 0.0) {
        return Err(MotionError::invalid(
            "interpolate",
            "learning_rate",
            "must be a positive number",
        ));
    }
    for (what, x) in [("input", input), ("target", target)] {
        if x.iter().any(|r| r.iter().any(|v| !v.is_finite())) {
            return Err(MotionError::invalid(
                "interpolate",
                what,
                "holds NaN or infinite values",
            ));
        }
    }
    // Continuous axis-angle trajectories: a linear change near the ±π seam
    // of a wrapped signal would turn into a rotation jump.
    let mut x0: Channels = input[..n].to_vec();
    let mut y: Channels = target[..n].to_vec();
    unwrap_axis_angle(&mut x0);
    unwrap_axis_angle(&mut y);
    let objective = build_objective(&x0, &y, opts)?;
    // Adam on the orthonormal DCT coefficients of each channel (x = Dᵀc, so
    // ∂L/∂c = D ∂L/∂x). For the DCT objective the gradient is zero outside
    // the band, so Adam leaves every other frequency untouched; STFT and PCA
    // gradients spread over all frequencies (the thesis's jitter).
    let dct = Dct::new(n);
    let to_coeffs = |x: &Channels| map_columns(x, |col| dct.forward(col));
    let from_coeffs = |c: &Channels| map_columns(c, |col| dct.inverse(col));
    let (b1, b2, eps) = (0.9, 0.999, 1e-8);
    // A coefficient step of lr·√(n/2) moves samples by about lr: the learning
    // rate keeps its meaning (radians per step) whatever the clip length.
    let lr = opts.learning_rate * (n as f64 / 2.0).sqrt();
    let mut x = x0;
    let mut coeffs = to_coeffs(&x);
    let mut g = vec![[0.0; CHANNELS]; n];
    let mut m1 = vec![[0.0; CHANNELS]; n];
    let mut m2 = vec![[0.0; CHANNELS]; n];
    let mut losses = Vec::with_capacity(opts.steps + 1);
    for step in 1..=opts.steps {
        let l = objective.loss_grad(&x, &mut g);
        losses.push(l);
        let gc = to_coeffs(&g);
        let (c1, c2) = (1.0 - b1f(b1, step), 1.0 - b1f(b2, step));
        for t in 0..n {
            for c in 0..CHANNELS {
                m1[t][c] = b1 * m1[t][c] + (1.0 - b1) * gc[t][c];
                m2[t][c] = b2 * m2[t][c] + (1.0 - b2) * gc[t][c] * gc[t][c];
                coeffs[t][c] -= lr * (m1[t][c] / c1) / ((m2[t][c] / c2).sqrt() + eps);
            }
        }
        x = from_coeffs(&coeffs);
    }
    losses.push(objective.loss_grad(&x, &mut g));
    wrap_all(&mut x);
    Ok(InterpolateResult {
        output: x,
        loss: losses,
        steps: opts.steps,
        frames: n,
    })
}

/// The objective for `opts` with its targets computed from `y` (and, for
/// PCA, a basis fitted on both clips). `x0` and `y` have equal length.
fn build_objective(
    x0: &Channels,
    y: &Channels,
    opts: &InterpolateOptions,
) -> Result<Box<dyn Objective>, MotionError> {
    let n = x0.len();
    let (lo, hi) = opts.band;
    Ok(match opts.objective {
        Embedding::Pose | Embedding::Lm => {
            return Err(MotionError::invalid(
                "interpolate",
                "objective",
                format!(
                    "the {} embedding is for search; interpolation moves dct, stft or pca features",
                    opts.objective.name()
                ),
            ))
        }
        Embedding::Dct => {
            let dct = Dct::new(n);
            let (lo_n, hi_n) = (scaled(lo, n), scaled(hi, n).max(scaled(lo, n) + 1).min(n));
            let target = (0..CHANNELS)
                .map(|c| {
                    let mut col = column(y, c);
                    dct.forward(&mut col);
                    col[lo_n..hi_n].to_vec()
                })
                .collect();
            Box::new(DctObjective {
                dct,
                lo: lo_n,
                hi: hi_n,
                target,
            })
        }
        Embedding::Stft => {
            let m = 16;
            let win: Vec<f64> = (0..m)
                .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / m as f64).cos())
                .collect();
            // Bin b of a 16-point FFT is b·60/16 Hz; the band's edges in Hz
            // are k·60/256 (128-frame DCT coefficient k).
            let hz = |k: usize| k as f64 * FEATURE_FPS / (2.0 * WINDOW as f64);
            let bin_hz = FEATURE_FPS / m as f64;
            let b_lo = (hz(lo) / bin_hz).floor() as usize;
            let b_hi = ((hz(hi) / bin_hz).ceil() as usize).clamp(b_lo + 1, m / 2 + 1);
            let mut o = StftObjective {
                win,
                hop: 8,
                bins: b_lo..b_hi,
                target: Vec::new(),
                fft: FftPlanner::new().plan_fft_forward(m),
            };
            o.target = (0..CHANNELS).map(|c| o.magnitudes(&column(y, c))).collect();
            Box::new(o)
        }
        Embedding::Pca => {
            let (xf, yf) = (f32_rows(&x0), f32_rows(y));
            let starts = window_starts(n, WINDOW);
            let wins: Vec<Vec<f32>> = window_starts(n, 32)
                .into_iter()
                .flat_map(|s| [window(&xf, s), window(&yf, s)])
                .collect();
            let pca = Pca::fit(wins.iter().map(|w| w.as_slice()))?;
            let (plo, phi) = (
                lo.min(COEFFS - 1),
                hi.min(COEFFS).max(lo.min(COEFFS - 1) + 1),
            );
            let mut o = PcaObjective {
                pca,
                lo: plo,
                hi: phi,
                starts: starts.clone(),
                target: Vec::new(),
            };
            o.target = starts
                .iter()
                .map(|&s| (0..CHANNELS).map(|c| o.project(y, s, c)).collect())
                .collect();
            Box::new(o)
        }
    })
}

fn b1f(b: f64, step: usize) -> f64 {
    b.powi(step as i32)
}

/// Closed form of the DCT objective's optimum: the input with its band
/// replaced by the target's (the oracle the optimiser is tested against).
pub fn dct_band_swap(input: &Channels, target: &Channels, band: (usize, usize)) -> Channels {
    let n = input.len().min(target.len());
    let dct = Dct::new(n);
    let (lo, hi) = (
        scaled(band.0, n),
        scaled(band.1, n).max(scaled(band.0, n) + 1).min(n),
    );
    let mut out = input[..n].to_vec();
    for c in 0..CHANNELS {
        let mut a = column(&out, c);
        let mut b = column(&target[..n], c);
        dct.forward(&mut a);
        dct.forward(&mut b);
        a[lo..hi].copy_from_slice(&b[lo..hi]);
        dct.inverse(&mut a);
        for t in 0..n {
            out[t][c] = a[t];
        }
    }
    out
}

/// Mean jerk of joint positions (m/s³): the third time difference of every
/// joint's position times fps³, its norm averaged over frames and joints.
pub fn mean_jerk(positions: &[crate::motion::rotation::Vec3], joints: usize, fps: f64) -> f64 {
    let per = frame_jerk(positions, joints, fps);
    per.iter().sum::<f64>() / per.len().max(1) as f64
}

/// Median over frames of the per-frame mean joint jerk (m/s³): unlike the
/// mean, a few single-frame capture glitches do not move it.
pub fn median_jerk(positions: &[crate::motion::rotation::Vec3], joints: usize, fps: f64) -> f64 {
    let mut per = frame_jerk(positions, joints, fps);
    if per.is_empty() {
        return 0.0;
    }
    per.sort_by(f64::total_cmp);
    per[per.len() / 2]
}

/// Jerk norm averaged over joints, for every frame that has three after it.
fn frame_jerk(positions: &[crate::motion::rotation::Vec3], joints: usize, fps: f64) -> Vec<f64> {
    let frames = positions.len() / joints.max(1);
    if frames < 4 {
        return vec![];
    }
    (0..frames - 3)
        .map(|f| {
            let mut sum = 0.0;
            for j in 0..joints {
                let p = |k: usize| positions[(f + k) * joints + j];
                let d: Vec<f64> = (0..3)
                    .map(|a| p(3)[a] - 3.0 * p(2)[a] + 3.0 * p(1)[a] - p(0)[a])
                    .collect();
                sum += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() * fps.powi(3);
            }
            sum / joints as f64
        })
        .collect()
}

#[cfg(test)]
mod tests;
