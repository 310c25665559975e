//! Music features for keyframe selection (thesis 001 §3.3.2, SPEC §6).
//!
//! Audio (WAV, Ogg Vorbis, MP3 via symphonia) is mixed to mono and
//! resampled to 30,720 Hz (a Kaiser-windowed sinc), so that a hop of 512
//! gives exactly 60 feature frames per second, one per 60 fps motion frame.
//! Then, following librosa's definitions (checked against librosa by
//! `scripts/check_audio_librosa.py`):
//!
//! - power spectrogram: STFT, periodic Hann of 2,048, hop 512, centred with
//!   zero padding;
//! - 128-band mel spectrogram (Slaney scale and normalisation, 0 Hz to
//!   Nyquist), in dB (`10·log10(max(S, 1e-10))`, floored 80 dB below the
//!   maximum);
//! - 20 MFCC: orthonormal DCT-II of the dB mel spectrogram;
//! - onset strength: mean over bands of the positive first difference of
//!   the dB mel spectrogram, shifted 3 frames (lag 1 + the centring
//!   offset) like librosa's;
//! - onset peaks: librosa's `onset_detect` peak picker on the [0, 1]
//!   normalised curve.
//!
//! Harmonic/percussive separation ([`hpss_percussive`]) is median
//! filtering (Fitzgerald 2010, as librosa's `hpss`): it stands in for the
//! thesis's neural drum-stem separation.

use crate::features::reflect_index;
use crate::motion::MotionError;
use rustfft::{num_complex::Complex, FftPlanner};

mod decode;
use decode::bad;
pub use decode::{decode, read, resample, Audio};

pub const SAMPLE_RATE: u32 = 30_720;
pub const N_FFT: usize = 2048;
pub const HOP: usize = 512;
pub const N_MELS: usize = 128;
pub const N_MFCC: usize = 20;
/// Feature frames per second (`SAMPLE_RATE / HOP`).
pub const FEATURE_FPS: f64 = 60.0;
/// Longest audio accepted, seconds.
pub const MAX_SECONDS: f64 = 3600.0;

/// `[frames][N_FFT/2 + 1]` power spectrogram (|X|²), centred STFT with zero
/// padding, periodic Hann.
pub fn power_spectrogram(y: &[f32]) -> Vec<Vec<f64>> {
    let pad = N_FFT / 2;
    let frames = 1 + y.len() / HOP;
    let window: Vec<f64> = (0..N_FFT)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / N_FFT as f64).cos())
        .collect();
    let fft = FftPlanner::<f64>::new().plan_fft_forward(N_FFT);
    let mut buf = vec![Complex::new(0.0, 0.0); N_FFT];
    (0..frames)
        .map(|t| {
            for (i, b) in buf.iter_mut().enumerate() {
                let k = (t * HOP + i) as i64 - pad as i64;
                let v = if k >= 0 && (k as usize) < y.len() {
                    y[k as usize] as f64
                } else {
                    0.0
                };
                *b = Complex::new(v * window[i], 0.0);
            }
            fft.process(&mut buf);
            buf[..N_FFT / 2 + 1].iter().map(|c| c.norm_sqr()).collect()
        })
        .collect()
}

fn hz_to_mel(f: f64) -> f64 {
    // Slaney: linear below 1 kHz, logarithmic above.
    let (f_sp, min_log_hz) = (200.0 / 3.0, 1000.0);
    let min_log_mel = min_log_hz / f_sp;
    let logstep = (6.4f64).ln() / 27.0;
    if f >= min_log_hz {
        min_log_mel + (f / min_log_hz).ln() / logstep
    } else {
        f / f_sp
    }
}

fn mel_to_hz(m: f64) -> f64 {
    let (f_sp, min_log_hz) = (200.0 / 3.0, 1000.0);
    let min_log_mel = min_log_hz / f_sp;
    let logstep = (6.4f64).ln() / 27.0;
    if m >= min_log_mel {
        min_log_hz * (logstep * (m - min_log_mel)).exp()
    } else {
        f_sp * m
    }
}

/// `[N_MELS][N_FFT/2 + 1]` Slaney mel filterbank (area-normalised).
pub fn mel_filterbank(sr: f64) -> Vec<Vec<f64>> {
    let bins = N_FFT / 2 + 1;
    let fft_freqs: Vec<f64> = (0..bins).map(|i| i as f64 * sr / N_FFT as f64).collect();
    let (lo, hi) = (hz_to_mel(0.0), hz_to_mel(sr / 2.0));
    let mel_f: Vec<f64> = (0..N_MELS + 2)
        .map(|i| mel_to_hz(lo + (hi - lo) * i as f64 / (N_MELS + 1) as f64))
        .collect();
    (0..N_MELS)
        .map(|m| {
            let (f0, f1, f2) = (mel_f[m], mel_f[m + 1], mel_f[m + 2]);
            let enorm = 2.0 / (f2 - f0);
            fft_freqs
                .iter()
                .map(|&f| {
                    let lower = (f - f0) / (f1 - f0);
                    let upper = (f2 - f) / (f2 - f1);
                    lower.min(upper).max(0.0) * enorm
                })
                .collect()
        })
        .collect()
}

/// `[frames][N_MELS]` mel power in dB, floored 80 dB below the maximum.
pub fn mel_db(power: &[Vec<f64>], sr: f64) -> Vec<Vec<f64>> {
    let fb = mel_filterbank(sr);
    let mut out: Vec<Vec<f64>> = power
        .iter()
        .map(|p| {
            fb.iter()
                .map(|w| {
                    let e: f64 = w.iter().zip(p).map(|(a, b)| a * b).sum();
                    10.0 * e.max(1e-10).log10()
                })
                .collect()
        })
        .collect();
    let max = out
        .iter()
        .flatten()
        .fold(f64::NEG_INFINITY, |a, &b| a.max(b));
    for row in out.iter_mut() {
        for v in row.iter_mut() {
            *v = v.max(max - 80.0);
        }
    }
    out
}

/// `[frames][N_MFCC]`: orthonormal DCT-II over the mel bands.
pub fn mfcc(mel_db: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let m = N_MELS as f64;
    let basis: Vec<Vec<f64>> = (0..N_MFCC)
        .map(|k| {
            let s = if k == 0 {
                (1.0 / m).sqrt()
            } else {
                (2.0 / m).sqrt()
            };
            (0..N_MELS)
                .map(|n| {
                    s * (std::f64::consts::PI * k as f64 * (2 * n + 1) as f64 / (2.0 * m)).cos()
                })
                .collect()
        })
        .collect();
    mel_db
        .iter()
        .map(|row| {
            basis
                .iter()
                .map(|b| b.iter().zip(row).map(|(x, y)| x * y).sum())
                .collect()
        })
        .collect()
}

/// Onset strength per frame (librosa's: lag 1, shifted by 1 + N_FFT/(2·HOP)).
pub fn onset_strength(mel_db: &[Vec<f64>]) -> Vec<f64> {
    let n = mel_db.len();
    let shift = 1 + N_FFT / (2 * HOP);
    let mut out = vec![0.0; n];
    for (i, o) in out.iter_mut().enumerate().skip(shift) {
        let src = i - shift; // diff between frames src+1 and src
        if src + 1 >= n {
            break;
        }
        let (a, b) = (&mel_db[src + 1], &mel_db[src]);
        *o = a.iter().zip(b).map(|(x, y)| (x - y).max(0.0)).sum::<f64>() / N_MELS as f64;
    }
    out
}

/// librosa's `onset_detect` peak picker at 60 frames/s: the curve is scaled
/// to [0, 1]; a frame is a peak when it is the maximum of frames
/// [n−1, n] and at least 0.07 above the mean of [n−6, n+6]; after a peak the
/// next frame is skipped. An all-zero curve has no peaks.
pub fn onset_peaks(curve: &[f64]) -> Vec<usize> {
    if curve.is_empty() {
        return vec![];
    }
    let min = curve.iter().copied().fold(f64::INFINITY, f64::min);
    let max = curve.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !(max > min) || curve.iter().any(|v| !v.is_finite()) {
        return vec![];
    }
    let x: Vec<f64> = curve
        .iter()
        .map(|v| (v - min) / (max - min + f64::MIN_POSITIVE))
        .collect();
    let (pre_max, post_max, pre_avg, post_avg, wait, delta) =
        (1usize, 1usize, 6usize, 7usize, 1usize, 0.07);
    let n = x.len();
    let mean = |a: usize, b: usize| x[a..b].iter().sum::<f64>() / (b - a) as f64;
    let maxr = |a: usize, b: usize| x[a..b].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut peaks = vec![];
    let first = x[0] >= maxr(0, post_max.min(n)) && x[0] >= mean(0, post_avg.min(n)) + delta;
    let mut i = if first {
        peaks.push(0);
        wait + 1
    } else {
        1
    };
    while i < n {
        let is_max = x[i] == maxr(i.saturating_sub(pre_max), (i + post_max).min(n));
        if is_max && x[i] >= mean(i.saturating_sub(pre_avg), (i + post_avg).min(n)) + delta {
            peaks.push(i);
            i += wait + 1;
        } else {
            i += 1;
        }
    }
    peaks
}

/// Median of a small slice (copied).
fn median(v: &mut [f64]) -> f64 {
    let m = v.len() / 2;
    let (_, x, _) = v.select_nth_unstable_by(m, f64::total_cmp);
    *x
}

/// The percussive part of a power spectrogram by median-filter HPSS
/// (kernel 31 frames / 31 bins, soft masks with power 2, as librosa's
/// `decompose.hpss` on the magnitude).
pub fn hpss_percussive(power: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (t_n, f_n) = (power.len(), power.first().map_or(0, |r| r.len()));
    let mag: Vec<Vec<f64>> = power
        .iter()
        .map(|r| r.iter().map(|p| p.sqrt()).collect())
        .collect();
    let k = 15i64; // half of 31
    let mut harm = vec![vec![0.0; f_n]; t_n];
    let mut perc = vec![vec![0.0; f_n]; t_n];
    let mut w = Vec::with_capacity(31);
    for t in 0..t_n {
        for f in 0..f_n {
            // Along time (harmonic), then along frequency (percussive),
            // edges reflected like scipy's median_filter.
            w.clear();
            w.extend((-k..=k).map(|d| mag[reflect_index(t as i64 + d, t_n)][f]));
            harm[t][f] = median(&mut w);
            w.clear();
            w.extend((-k..=k).map(|d| mag[t][reflect_index(f as i64 + d, f_n)]));
            perc[t][f] = median(&mut w);
        }
    }
    (0..t_n)
        .map(|t| {
            (0..f_n)
                .map(|f| {
                    let (h, p) = (harm[t][f].powi(2), perc[t][f].powi(2));
                    let mask = if h + p > 0.0 { p / (h + p) } else { 0.5 };
                    let m = mag[t][f] * mask;
                    m * m
                })
                .collect()
        })
        .collect()
}

/// Non-negative matrix factor deconvolution (Smaragdis 2004) of a
/// `[frames][bins]` non-negative spectrogram V into `r` components, each a
/// spectro-temporal template `W[τ]` of `len` frames and an activation row
/// `H`, with V ≈ Σ_τ W[τ] · shift_τ(H). Multiplicative updates for the
/// generalised KL divergence, `iters` rounds, seeded start. Returns the
/// activations `[r][frames]`.
pub fn nmfd(v: &[Vec<f64>], r: usize, len: usize, iters: usize, seed: u64) -> Vec<Vec<f64>> {
    use rand::{Rng, SeedableRng};
    let (t_n, f_n) = (v.len(), v.first().map_or(0, |x| x.len()));
    if t_n == 0 || f_n == 0 || r == 0 || len == 0 {
        return vec![vec![0.0; t_n]; r];
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let scale = v.iter().flatten().sum::<f64>() / (t_n * f_n) as f64;
    // w[τ][k][f], h[k][t]
    let mut w: Vec<Vec<Vec<f64>>> = (0..len)
        .map(|_| {
            (0..r)
                .map(|_| (0..f_n).map(|_| rng.gen_range(0.1..1.0)).collect())
                .collect()
        })
        .collect();
    let mut h: Vec<Vec<f64>> = (0..r)
        .map(|_| {
            (0..t_n)
                .map(|_| rng.gen_range(0.1..1.0) * scale.max(1e-12))
                .collect()
        })
        .collect();
    let eps = 1e-12;
    let approx = |w: &Vec<Vec<Vec<f64>>>, h: &Vec<Vec<f64>>| -> Vec<Vec<f64>> {
        let mut lam = vec![vec![eps; f_n]; t_n];
        for (tau, wt) in w.iter().enumerate() {
            for (k, wk) in wt.iter().enumerate() {
                for t in tau..t_n {
                    let a = h[k][t - tau];
                    if a == 0.0 {
                        continue;
                    }
                    for (l, x) in lam[t].iter_mut().zip(wk) {
                        *l += a * x;
                    }
                }
            }
        }
        lam
    };
    for _ in 0..iters {
        // H update (averaged over τ).
        let lam = approx(&w, &h);
        let ratio: Vec<Vec<f64>> = v
            .iter()
            .zip(&lam)
            .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x / y).collect())
            .collect();
        for k in 0..r {
            let mut num = vec![0.0; t_n];
            let mut den = vec![0.0; t_n];
            for (tau, wt) in w.iter().enumerate() {
                let wsum: f64 = wt[k].iter().sum();
                for t in 0..t_n.saturating_sub(tau) {
                    num[t] += wt[k]
                        .iter()
                        .zip(&ratio[t + tau])
                        .map(|(a, b)| a * b)
                        .sum::<f64>();
                    den[t] += wsum;
                }
            }
            for t in 0..t_n {
                h[k][t] *= num[t] / den[t].max(eps);
            }
        }
        // W update.
        let lam = approx(&w, &h);
        let ratio: Vec<Vec<f64>> = v
            .iter()
            .zip(&lam)
            .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x / y).collect())
            .collect();
        for (tau, wt) in w.iter_mut().enumerate() {
            for (k, wk) in wt.iter_mut().enumerate() {
                let hsum: f64 = h[k][..t_n - tau.min(t_n)].iter().sum();
                let mut num = vec![0.0; f_n];
                for t in tau..t_n {
                    let a = h[k][t - tau];
                    if a == 0.0 {
                        continue;
                    }
                    for (n, x) in num.iter_mut().zip(&ratio[t]) {
                        *n += a * x;
                    }
                }
                for (x, n) in wk.iter_mut().zip(&num) {
                    *x *= n / hsum.max(eps);
                }
            }
        }
    }
    h
}

/// The NMFD activation curve of the percussive part: 3 components with
/// 8-frame templates over the percussive mel power, each activation row
/// scaled to a maximum of 1, summed with equal weights.
pub fn nmfd_curve(percussive_power: &[Vec<f64>]) -> Vec<f64> {
    let fb = mel_filterbank(SAMPLE_RATE as f64);
    let mel: Vec<Vec<f64>> = percussive_power
        .iter()
        .map(|p| {
            fb.iter()
                .map(|w| w.iter().zip(p).map(|(a, b)| a * b).sum::<f64>().sqrt())
                .collect()
        })
        .collect();
    let h = nmfd(&mel, 3, 8, 30, 0x4e4d4644);
    let n = mel.len();
    let mut curve = vec![0.0; n];
    for row in &h {
        let m = row.iter().copied().fold(0.0, f64::max);
        if m > 0.0 {
            curve.iter_mut().zip(row).for_each(|(c, v)| *c += v / m);
        }
    }
    curve
}

/// Everything keyframe selection needs from a piece of music, at 60 frames/s.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MusicFeatures {
    pub frames: usize,
    pub mfcc: Vec<Vec<f64>>,
    pub onset: Vec<f64>,
    pub peaks: Vec<usize>,
    /// Onset strength of the HPSS percussive part, and its peaks.
    pub percussive_onset: Vec<f64>,
    pub percussive_peaks: Vec<usize>,
    /// NMFD activation curve of the percussive part, and its peaks.
    pub nmfd: Vec<f64>,
    pub nmfd_peaks: Vec<usize>,
    pub seconds: f64,
    pub source_rate: u32,
    pub channels: usize,
}

/// Resample to 30,720 Hz and compute the features.
pub fn analyse(audio: &Audio, name: &str) -> Result<(Vec<f32>, MusicFeatures), MotionError> {
    if audio.seconds() < N_FFT as f64 / SAMPLE_RATE as f64 / 2.0 {
        return Err(bad(
            name,
            "audio",
            format!(
                "{:.3} s is too short for one analysis frame",
                audio.seconds()
            ),
        ));
    }
    let y = resample(&audio.samples, audio.sample_rate, SAMPLE_RATE);
    let power = power_spectrogram(&y);
    let db = mel_db(&power, SAMPLE_RATE as f64);
    let onset = onset_strength(&db);
    let peaks = onset_peaks(&onset);
    let perc = hpss_percussive(&power);
    let pdb = mel_db(&perc, SAMPLE_RATE as f64);
    let percussive_onset = onset_strength(&pdb);
    let percussive_peaks = onset_peaks(&percussive_onset);
    let nmfd = nmfd_curve(&perc);
    let nmfd_peaks = onset_peaks(&nmfd);
    Ok((
        y,
        MusicFeatures {
            frames: power.len(),
            mfcc: mfcc(&db),
            onset,
            peaks,
            percussive_onset,
            percussive_peaks,
            nmfd,
            nmfd_peaks,
            seconds: audio.seconds(),
            source_rate: audio.sample_rate,
            channels: audio.channels,
        },
    ))
}

/// A metronome: a 20 ms, 1.5 kHz click with a fast decay on every beat.
pub fn metronome(bpm: f64, seconds: f64, sample_rate: u32) -> Result<Audio, MotionError> {
    if !(bpm.is_finite() && (20.0..=400.0).contains(&bpm)) {
        return Err(bad("metronome", "bpm", format!("{bpm}; need 20..=400")));
    }
    if !(seconds > 0.0 && seconds <= MAX_SECONDS) {
        return Err(bad(
            "metronome",
            "seconds",
            format!("{seconds}; need (0, {MAX_SECONDS}]"),
        ));
    }
    let n = (seconds * sample_rate as f64).round() as usize;
    let mut y = vec![0f32; n];
    let click = (0.02 * sample_rate as f64) as usize;
    let step = 60.0 / bpm * sample_rate as f64;
    let mut b = 0usize;
    loop {
        let s = (b as f64 * step).round() as usize;
        if s >= n {
            break;
        }
        for i in 0..click.min(n - s) {
            let t = i as f64 / sample_rate as f64;
            y[s + i] =
                (0.8 * (2.0 * std::f64::consts::PI * 1500.0 * t).sin() * (-t / 0.004).exp()) as f32;
        }
        b += 1;
    }
    Ok(Audio {
        sample_rate,
        samples: y,
        channels: 1,
    })
}

#[cfg(test)]
mod tests;
