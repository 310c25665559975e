//! Motion → tokens (thesis 000 §4.4, SPEC §4). Pure.
//!
//! A [`Series`] is a `[frames][channels]` matrix of axis-angle components
//! (and optionally other per-frame values). A [`Codec`] turns it into
//! *words* — one per frame for the per-value binning codecs ([`Uniform`],
//! [`Quantile`]), one per tile for the JPEG-like [`tile::TileCodec`] — and
//! back. Words are sequences of symbols from the codec's alphabet; a
//! separator token between words is implied and counted by the metrics.
//!
//! [`vocab::Vocabulary`] is the concrete token layout the language model
//! uses (SPEC §4: 13 joints × 3 + 3 root tokens + separator = 43 tokens a
//! frame, special and conditioning tokens), shared by the trainer and the
//! server through its JSON form.

pub mod eval;
pub mod tile;
pub mod vocab;

use crate::motion::rotation::{geodesic_axis_angle, unwrap_axis_angle_rows, wrap_axis_angle_rows};
use crate::motion::MotionError;
use std::f64::consts::PI;

/// A `[frames][channels]` matrix, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub channels: usize,
    pub data: Vec<f64>,
}

impl Series {
    pub fn new(channels: usize, data: Vec<f64>) -> Result<Series, MotionError> {
        if channels == 0 || data.len() % channels != 0 {
            return Err(MotionError::invalid(
                "series",
                "channels",
                format!("{} values do not split into rows of {channels}", data.len()),
            ));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(MotionError::invalid(
                "series",
                "values",
                format!(
                    "non-finite value at frame {}, channel {}",
                    i / channels,
                    i % channels
                ),
            ));
        }
        Ok(Series { channels, data })
    }
    pub fn frames(&self) -> usize {
        self.data.len() / self.channels
    }
    pub fn row(&self, t: usize) -> &[f64] {
        &self.data[t * self.channels..(t + 1) * self.channels]
    }
    /// The first `frames` rows.
    pub fn truncated(mut self, frames: usize) -> Series {
        self.data.truncate(frames * self.channels);
        self
    }
}

/// Encode / decode between a series and words of symbols.
pub trait Codec {
    /// A short name with the settings, e.g. `uniform-360`.
    fn describe(&self) -> String;
    /// Number of distinct symbols (the separator not included).
    fn alphabet(&self) -> usize;
    /// Frames a word covers.
    fn frames_per_word(&self) -> usize;
    /// Channels the codec expects.
    fn channels(&self) -> usize;
    fn encode(&self, x: &Series) -> Result<Vec<Vec<u32>>, MotionError>;
    /// The decoded series: `words × frames_per_word` frames (the caller
    /// truncates to the original length).
    fn decode(&self, words: &[Vec<u32>]) -> Result<Series, MotionError>;
}

fn check_channels(codec: &dyn Codec, x: &Series) -> Result<(), MotionError> {
    if x.channels != codec.channels() {
        return Err(MotionError::invalid(
            "series",
            "channels",
            format!(
                "{} expects {} channels, got {}",
                codec.describe(),
                codec.channels(),
                x.channels
            ),
        ));
    }
    Ok(())
}

fn bad_symbol(codec: &dyn Codec, word: usize, pos: usize, s: u32) -> MotionError {
    MotionError::invalid(
        "tokens",
        format!("word {word}, symbol {pos}"),
        format!(
            "symbol {s} is outside {}'s alphabet of {}",
            codec.describe(),
            codec.alphabet()
        ),
    )
}

/// Uniform bins over `[lo, hi]`: symbol `k` stands for the bin centre
/// `lo + (k + ½)·w`, `w = (hi − lo)/bins`; values outside are clamped.
#[derive(Clone, Debug, PartialEq)]
pub struct UniformBins {
    pub bins: usize,
    pub lo: f64,
    pub hi: f64,
}

impl UniformBins {
    pub fn new(bins: usize, lo: f64, hi: f64) -> Result<Self, MotionError> {
        if bins < 2 || bins > 1 << 20 || !(lo < hi) || !lo.is_finite() || !hi.is_finite() {
            return Err(MotionError::invalid(
                "tokenizer",
                "bins",
                format!("need 2..=1048576 bins over a finite range lo < hi, got {bins} over [{lo}, {hi}]"),
            ));
        }
        Ok(UniformBins { bins, lo, hi })
    }
    /// An axis-angle component's bins: uniform over [−π, π] (SPEC §4).
    pub fn angles(bins: usize) -> UniformBins {
        UniformBins {
            bins,
            lo: -PI,
            hi: PI,
        }
    }
    pub fn width(&self) -> f64 {
        (self.hi - self.lo) / self.bins as f64
    }
    pub fn encode(&self, v: f64) -> u32 {
        let k = ((v - self.lo) / self.width()).floor();
        k.clamp(0.0, (self.bins - 1) as f64) as u32
    }
    pub fn decode(&self, k: u32) -> f64 {
        self.lo + (k as f64 + 0.5) * self.width()
    }
}

/// Per-value uniform binning of axis-angle components over `[−π, π]`
/// (SPEC §4: 360 bins, 1° each). Axis-angle vectors are wrapped to
/// `|θ| ≤ π` first, so every component lies in range and the error is at
/// most half a bin per component.
#[derive(Clone, Debug)]
pub struct Uniform {
    pub bins: UniformBins,
    pub channels: usize,
}

impl Uniform {
    pub fn new(bins: usize, channels: usize) -> Result<Self, MotionError> {
        Ok(Uniform {
            bins: UniformBins::new(bins, -PI, PI)?,
            channels,
        })
    }
}

impl Codec for Uniform {
    fn describe(&self) -> String {
        format!("uniform-{}", self.bins.bins)
    }
    fn alphabet(&self) -> usize {
        self.bins.bins
    }
    fn frames_per_word(&self) -> usize {
        1
    }
    fn channels(&self) -> usize {
        self.channels
    }
    fn encode(&self, x: &Series) -> Result<Vec<Vec<u32>>, MotionError> {
        check_channels(self, x)?;
        let w = wrap_joints(x);
        Ok((0..w.frames())
            .map(|t| w.row(t).iter().map(|&v| self.bins.encode(v)).collect())
            .collect())
    }
    fn decode(&self, words: &[Vec<u32>]) -> Result<Series, MotionError> {
        decode_per_value(self, words, |_, k| self.bins.decode(k))
    }
}

fn decode_per_value(
    codec: &dyn Codec,
    words: &[Vec<u32>],
    value: impl Fn(usize, u32) -> f64,
) -> Result<Series, MotionError> {
    let c = codec.channels();
    let mut data = Vec::with_capacity(words.len() * c);
    for (i, w) in words.iter().enumerate() {
        if w.len() != c {
            return Err(MotionError::invalid(
                "tokens",
                format!("word {i}"),
                format!("has {} symbols, {} expects {c}", w.len(), codec.describe()),
            ));
        }
        for (p, &s) in w.iter().enumerate() {
            if s as usize >= codec.alphabet() {
                return Err(bad_symbol(codec, i, p, s));
            }
            data.push(value(p, s));
        }
    }
    Series::new(c, data)
}

/// Per-channel quantile bins fitted on data: each channel's values are cut
/// at its `k/bins` empirical quantiles; a symbol decodes to the median of
/// the fitted values in its bin.
#[derive(Clone, Debug)]
pub struct Quantile {
    pub bins: usize,
    /// `[channel][bins − 1]` ascending cut points.
    pub edges: Vec<Vec<f64>>,
    /// `[channel][bins]` decoded values.
    pub centres: Vec<Vec<f64>>,
}

/// Quantile cut points and bin medians of one channel's values: the cut
/// points are the `k/bins` empirical quantiles; a bin decodes to the median
/// of the fitted values that fall in it (an empty bin, which only ties can
/// make, to its upper cut point).
pub fn quantile_bins(mut v: Vec<f64>, bins: usize) -> (Vec<f64>, Vec<f64>) {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return (vec![0.0; bins - 1], vec![0.0; bins]);
    }
    let at = |q: f64| -> f64 { v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)] };
    let edges: Vec<f64> = (1..bins).map(|k| at(k as f64 / bins as f64)).collect();
    let mut centres = Vec::with_capacity(bins);
    let mut i = 0;
    for k in 0..bins {
        let start = i;
        while i < v.len() && (k + 1 == bins || v[i] <= edges[k]) {
            i += 1;
        }
        centres.push(if i > start {
            v[start + (i - start) / 2]
        } else if k + 1 < bins {
            edges[k]
        } else {
            v[v.len() - 1]
        });
    }
    (edges, centres)
}

/// The bin of `v` given ascending cut points: the number of cut points
/// below `v` (a value equal to a cut point goes to the lower bin).
pub fn quantile_encode(edges: &[f64], v: f64) -> u32 {
    edges.partition_point(|&e| e < v) as u32
}

impl Quantile {
    /// Fit on series (all with the same channel count).
    pub fn fit(data: &[&Series], bins: usize) -> Result<Quantile, MotionError> {
        let c = data.first().map(|s| s.channels).ok_or_else(|| {
            MotionError::invalid("tokenizer", "data", "no series to fit quantile bins on")
        })?;
        if bins < 2 {
            return Err(MotionError::invalid(
                "tokenizer",
                "bins",
                "need at least 2 bins",
            ));
        }
        let wrapped: Vec<Series> = data.iter().map(|s| wrap_joints(s)).collect();
        let mut edges = Vec::with_capacity(c);
        let mut centres = Vec::with_capacity(c);
        for ch in 0..c {
            let v: Vec<f64> = wrapped
                .iter()
                .flat_map(|s| (0..s.frames()).map(move |t| s.row(t)[ch]))
                .collect();
            let (e, m) = quantile_bins(v, bins);
            edges.push(e);
            centres.push(m);
        }
        Ok(Quantile {
            bins,
            edges,
            centres,
        })
    }
}

impl Codec for Quantile {
    fn describe(&self) -> String {
        format!("quantile-{}", self.bins)
    }
    fn alphabet(&self) -> usize {
        self.bins
    }
    fn frames_per_word(&self) -> usize {
        1
    }
    fn channels(&self) -> usize {
        self.edges.len()
    }
    fn encode(&self, x: &Series) -> Result<Vec<Vec<u32>>, MotionError> {
        check_channels(self, x)?;
        let w = wrap_joints(x);
        Ok((0..w.frames())
            .map(|t| {
                w.row(t)
                    .iter()
                    .enumerate()
                    .map(|(c, &v)| quantile_encode(&self.edges[c], v))
                    .collect()
            })
            .collect())
    }
    fn decode(&self, words: &[Vec<u32>]) -> Result<Series, MotionError> {
        decode_per_value(self, words, |c, k| self.centres[c][k as usize])
    }
}

/// Every consecutive triple of a series wrapped to an axis-angle with
/// `|θ| ≤ π` (a trailing partial triple is left as is).
pub fn wrap_joints(x: &Series) -> Series {
    let mut out = x.clone();
    wrap_axis_angle_rows(&mut out.data, x.channels);
    out
}

/// Make each joint's axis-angle continuous over time (see
/// [`unwrap_axis_angle_rows`]), for any channel count.
pub fn unwrap_joints(x: &mut Series) {
    unwrap_axis_angle_rows(&mut x.data, x.channels);
}

/// Geodesic reconstruction error between two axis-angle series (radians,
/// per joint per frame): the angle of `R_aᵀ R_b`. The 99th percentile comes
/// from a histogram of 0.01° bins.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeodesicError {
    pub mean: f64,
    pub max: f64,
    pub count: usize,
    hist: Vec<u32>,
}

const HIST_BINS: usize = 18_001;

impl GeodesicError {
    pub fn between(a: &Series, b: &Series) -> GeodesicError {
        let mut e = GeodesicError::default();
        e.add(a, b);
        e
    }
    /// Accumulate the joints of the frames both have.
    pub fn add(&mut self, a: &Series, b: &Series) {
        if self.hist.is_empty() {
            self.hist = vec![0; HIST_BINS];
        }
        let frames = a.frames().min(b.frames());
        let joints = a.channels.min(b.channels) / 3;
        let mut sum = self.mean * self.count as f64;
        for t in 0..frames {
            let (ra, rb) = (a.row(t), b.row(t));
            for j in 0..joints {
                let g = geodesic_axis_angle(
                    [ra[3 * j], ra[3 * j + 1], ra[3 * j + 2]],
                    [rb[3 * j], rb[3 * j + 1], rb[3 * j + 2]],
                );
                sum += g;
                self.max = self.max.max(g);
                self.count += 1;
                self.hist[((g.to_degrees() * 100.0) as usize).min(HIST_BINS - 1)] += 1;
            }
        }
        self.mean = if self.count > 0 {
            sum / self.count as f64
        } else {
            0.0
        };
    }
    /// The error (radians) that `q` of the joints stay under, to 0.01°.
    pub fn quantile(&self, q: f64) -> f64 {
        let target = (q * self.count as f64).ceil() as u64;
        let mut seen = 0u64;
        for (i, &n) in self.hist.iter().enumerate() {
            seen += n as u64;
            if seen >= target && n > 0 {
                return ((i + 1) as f64 / 100.0).to_radians().min(self.max);
            }
        }
        self.max
    }
}

/// Bits a fixed-length code needs for an alphabet of `n` symbols plus the
/// word separator.
pub fn bits_per_symbol(alphabet: usize) -> u32 {
    usize::BITS - alphabet.leading_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    pub(crate) fn random_rotations(frames: usize, joints: usize, seed: u64) -> Series {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut data = Vec::with_capacity(frames * joints * 3);
        for _ in 0..frames * joints {
            // A random axis and an angle in [0, π].
            let v: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-9);
            let th = rng.gen_range(0.0..PI);
            data.extend(v.iter().map(|c| c / n * th));
        }
        Series::new(joints * 3, data).unwrap()
    }

    #[test]
    fn uniform_error_is_at_most_half_a_bin_per_component() {
        let x = random_rotations(500, 13, 7);
        for bins in [8, 36, 360, 1000] {
            let u = Uniform::new(bins, 39).unwrap();
            let words = u.encode(&x).unwrap();
            assert!(words.iter().all(|w| w.len() == 39));
            let y = u.decode(&words).unwrap();
            let half = PI / bins as f64;
            let worst = x
                .data
                .iter()
                .zip(&y.data)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(worst <= half + 1e-12, "{bins} bins: {worst} > {half}");
        }
    }

    #[test]
    fn uniform_bins_by_hand() {
        let b = UniformBins::new(4, -2.0, 2.0).unwrap();
        assert_eq!(
            [-2.0, -1.01, -0.5, 0.0, 0.99, 1.5, 2.0, 9.0].map(|v| b.encode(v)),
            [0, 0, 1, 2, 2, 3, 3, 3]
        );
        assert_eq!([0, 1, 2, 3].map(|k| b.decode(k)), [-1.5, -0.5, 0.5, 1.5]);
        assert!(UniformBins::new(1, 0.0, 1.0).is_err());
        assert!(UniformBins::new(4, 1.0, 1.0).is_err());
    }

    #[test]
    fn quantile_bins_are_equally_filled_and_decode_inside_their_bin() {
        let x = random_rotations(2000, 2, 3);
        let q = Quantile::fit(&[&x], 10).unwrap();
        let words = q.encode(&x).unwrap();
        for c in 0..6 {
            let mut counts = [0usize; 10];
            words.iter().for_each(|w| counts[w[c] as usize] += 1);
            assert!(
                counts.iter().all(|&n| (150..=250).contains(&n)),
                "{counts:?}"
            );
        }
        let y = q.decode(&words).unwrap();
        for (t, w) in words.iter().enumerate() {
            for c in 0..6 {
                let k = w[c] as usize;
                let e = &q.edges[c];
                let v = y.row(t)[c];
                if k > 0 {
                    assert!(v >= e[k - 1]);
                }
                if k < 9 {
                    assert!(v <= e[k]);
                }
            }
        }
        // 360 quantile bins beat 360 uniform bins on data that is not uniform.
        let q360 = Quantile::fit(&[&x], 360).unwrap();
        let u360 = Uniform::new(360, 6).unwrap();
        let eq = GeodesicError::between(&x, &q360.decode(&q360.encode(&x).unwrap()).unwrap());
        let eu = GeodesicError::between(&x, &u360.decode(&u360.encode(&x).unwrap()).unwrap());
        assert!(eq.mean < eu.mean * 1.5, "{eq:?} vs {eu:?}");
    }

    #[test]
    fn bad_words_are_errors() {
        let u = Uniform::new(360, 6).unwrap();
        assert!(u.decode(&[vec![0; 5]]).is_err());
        assert!(u.decode(&[vec![360; 6]]).is_err());
        assert!(u.encode(&Series::new(3, vec![0.0; 9]).unwrap()).is_err());
        assert!(Series::new(3, vec![f64::NAN; 3]).is_err());
        assert!(Series::new(3, vec![0.0; 4]).is_err());
    }

    #[test]
    fn geodesic_error_of_a_known_turn() {
        let a = Series::new(3, vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.5]).unwrap();
        let b = Series::new(3, vec![0.0, 0.1, 0.0, 0.0, 0.0, 0.2]).unwrap();
        let e = GeodesicError::between(&a, &b);
        assert!((e.max - 0.3).abs() < 1e-12 && (e.mean - 0.2).abs() < 1e-12);
        assert!((e.quantile(0.5) - 0.1).abs() < 2e-4 && e.quantile(0.99) == e.max);
        assert_eq!(bits_per_symbol(360), 9);
        assert_eq!(bits_per_symbol(511), 9);
        assert_eq!(bits_per_symbol(512), 10);
    }
}
