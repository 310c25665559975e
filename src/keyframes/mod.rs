//! Keyframe selection and in-between reconstruction (thesis 001 §3.4–3.5,
//! SPEC §6). Pure.
//!
//! Selection returns sorted frame indices that always hold the first and the
//! last frame:
//! - [`even`]: evenly spaced (rounded);
//! - [`from_peaks`]: the strongest peaks of an onset-like curve, with the
//!   thesis's rules for peaks near the ends and for too few peaks;
//! - [`dp`]: dynamic programming (after Roberts 2018) that minimises, exactly,
//!   the summed squared error of reconstructing every frame's joint positions
//!   by linear interpolation between consecutive keyframes.
//!
//! In-betweens ([`inbetween`]): root lerp + per-joint quaternion SLERP; cubic
//! Bézier per segment with least-squares inner control points; Bézier with
//! control-point offsets averaged over training data.

pub mod inbetween;
pub mod metrics;

use crate::motion::rotation::Vec3;
use crate::motion::MotionError;

fn bad(field: &str, reason: String) -> MotionError {
    MotionError::invalid("keyframes", field, reason)
}

/// Check a keyframe count against a clip length.
pub fn check_count(frames: usize, count: usize) -> Result<(), MotionError> {
    if frames < 2 {
        return Err(bad(
            "frames",
            format!("a clip of {frames} frame(s) has no in-betweens"),
        ));
    }
    if count < 2 || count > frames {
        return Err(bad(
            "count",
            format!("{count} keyframes for {frames} frames; need 2..={frames} (first and last are always kept)"),
        ));
    }
    Ok(())
}

/// `count` evenly spaced keyframes over `frames` frames.
pub fn even(frames: usize, count: usize) -> Result<Vec<usize>, MotionError> {
    check_count(frames, count)?;
    let mut k: Vec<usize> = (0..count)
        .map(|i| ((i as f64) * (frames - 1) as f64 / (count - 1) as f64).round() as usize)
        .collect();
    k.dedup();
    Ok(k)
}

/// Local maxima of a curve (strictly greater than the left neighbour, at
/// least the right one), interior frames only.
pub fn peaks(curve: &[f64]) -> Vec<usize> {
    (1..curve.len().saturating_sub(1))
        .filter(|&i| curve[i] > curve[i - 1] && curve[i] >= curve[i + 1])
        .collect()
}

/// Keyframes from the peaks of an onset curve (thesis 001 §3.4.2): peaks
/// within `guard` frames of either end are dropped; the `count − 2`
/// strongest remaining peaks are taken (ties: earlier first); while keyframes
/// run short, the midpoint of the adjacent keyframe pair with the highest
/// summed curve value (among pairs with room between them) is added.
pub fn from_peaks(
    curve: &[f64],
    peak_frames: &[usize],
    count: usize,
    guard: usize,
) -> Result<Vec<usize>, MotionError> {
    let frames = curve.len();
    check_count(frames, count)?;
    if curve.iter().any(|v| !v.is_finite()) {
        return Err(bad("curve", "holds NaN or infinite values".into()));
    }
    let mut cand: Vec<usize> = peak_frames
        .iter()
        .copied()
        .filter(|&p| p > guard && p + guard < frames - 1 && p < frames)
        .collect();
    cand.sort_by(|&a, &b| curve[b].total_cmp(&curve[a]).then(a.cmp(&b)));
    cand.dedup();
    let mut keys: Vec<usize> = vec![0, frames - 1];
    keys.extend(cand.into_iter().take(count - 2));
    keys.sort_unstable();
    keys.dedup();
    while keys.len() < count {
        let best = keys
            .windows(2)
            .enumerate()
            .filter(|(_, w)| w[1] - w[0] >= 2)
            .max_by(|(_, a), (_, b)| {
                (curve[a[0]] + curve[a[1]])
                    .total_cmp(&(curve[b[0]] + curve[b[1]]))
                    .then((a[1] - a[0]).cmp(&(b[1] - b[0])))
            })
            .map(|(i, _)| i);
        let Some(i) = best else { break };
        let mid = (keys[i] + keys[i + 1]) / 2;
        keys.insert(i + 1, mid);
    }
    Ok(keys)
}

/// Beat frames of a metronome at `bpm` starting at frame 0, within
/// `frames` frames at `fps`.
pub fn beat_frames(bpm: f64, fps: f64, frames: usize) -> Result<Vec<usize>, MotionError> {
    if !(bpm.is_finite() && (20.0..=400.0).contains(&bpm)) {
        return Err(bad("bpm", format!("{bpm}; need 20..=400 beats per minute")));
    }
    let step = 60.0 / bpm * fps;
    Ok((0..)
        .map(|i| (i as f64 * step).round() as usize)
        .take_while(|&f| f < frames)
        .collect())
}

/// Frames per 4/4 measure (thesis 001 Eq. 3.1).
pub fn frames_per_measure(bpm: f64, fps: f64) -> f64 {
    60.0 / bpm * 4.0 * fps
}

/// Prefix sums that give, in O(dims), the summed squared error of
/// reconstructing frames `i..=j` of a curve by linear interpolation between
/// frames `i` and `j`.
pub struct SegmentCost {
    dims: usize,
    /// Σ x_t (per dim), Σ t·x_t (per dim), Σ |x_t|².
    s1: Vec<f64>,
    st: Vec<f64>,
    s2: Vec<f64>,
    x: Vec<f64>,
}

impl SegmentCost {
    /// `x` is `[frames][dims]` row-major.
    pub fn new(x: Vec<f64>, dims: usize) -> SegmentCost {
        let n = x.len() / dims;
        let mut s1 = vec![0.0; (n + 1) * dims];
        let mut st = vec![0.0; (n + 1) * dims];
        let mut s2 = vec![0.0; n + 1];
        for t in 0..n {
            let row = &x[t * dims..(t + 1) * dims];
            for d in 0..dims {
                s1[(t + 1) * dims + d] = s1[t * dims + d] + row[d];
                st[(t + 1) * dims + d] = st[t * dims + d] + t as f64 * row[d];
            }
            s2[t + 1] = s2[t] + row.iter().map(|v| v * v).sum::<f64>();
        }
        SegmentCost {
            dims,
            s1,
            st,
            s2,
            x,
        }
    }

    pub fn frames(&self) -> usize {
        self.x.len() / self.dims
    }

    /// Σ_{t=i..=j} |x_t − (x_i + u_t (x_j − x_i))|², u_t = (t − i)/(j − i).
    pub fn cost(&self, i: usize, j: usize) -> f64 {
        if j <= i + 1 {
            return 0.0;
        }
        let d = self.dims;
        let l = (j - i) as f64;
        let n = (j - i + 1) as f64;
        // Σu = (L+1)/2 and Σu² = (L+1)(2L+1)/(6L) over t = i..=j.
        let su = n / 2.0;
        let su2 = (l + 1.0) * (2.0 * l + 1.0) / (6.0 * l);
        let xi = &self.x[i * d..(i + 1) * d];
        let xj = &self.x[j * d..(j + 1) * d];
        let mut total = self.s2[j + 1] - self.s2[i];
        for k in 0..d {
            let sx = self.s1[(j + 1) * d + k] - self.s1[i * d + k];
            let stx = self.st[(j + 1) * d + k] - self.st[i * d + k];
            // Σ u_t x_t = (Σ t x_t − i Σ x_t) / L
            let sux = (stx - i as f64 * sx) / l;
            let a = xi[k];
            let b = xj[k] - xi[k];
            // Σ (x − a − u b)² = Σx² − 2aΣx − 2bΣux + n a² + 2ab Σu + b² Σu²
            total += -2.0 * a * sx - 2.0 * b * sux + n * a * a + 2.0 * a * b * su + b * b * su2;
        }
        total.max(0.0)
    }
}

/// Exact dynamic programming over keyframe sets: the `count` keyframes
/// (first and last included) minimising Σ cost(kᵢ, kᵢ₊₁). With `max_gap`,
/// consecutive keyframes are at most that far apart (faster; exact under
/// that constraint). O(count · frames · gap · dims).
pub fn dp(
    cost: &SegmentCost,
    count: usize,
    max_gap: Option<usize>,
) -> Result<(Vec<usize>, f64), MotionError> {
    let n = cost.frames();
    check_count(n, count)?;
    let gap = max_gap.unwrap_or(n).max(1);
    if (count - 1) * gap < n - 1 {
        return Err(bad(
            "max_gap",
            format!("{count} keyframes {gap} frames apart cannot span {n} frames"),
        ));
    }
    // Segment costs are shared by every keyframe count: computed once when
    // they fit in memory (row j holds i = j − gap .. j − 1).
    let lo_of = |j: usize| j.saturating_sub(gap);
    let mut starts = Vec::with_capacity(n + 1);
    let mut total_pairs = 0usize;
    for j in 0..n {
        starts.push(total_pairs);
        total_pairs += j - lo_of(j);
    }
    starts.push(total_pairs);
    let table: Option<Vec<f64>> = (total_pairs <= 50_000_000).then(|| {
        let mut t = Vec::with_capacity(total_pairs);
        for j in 0..n {
            for i in lo_of(j)..j {
                t.push(cost.cost(i, j));
            }
        }
        t
    });
    // best[k][j]: least cost of k+1 keyframes from 0 ending at j.
    let inf = f64::INFINITY;
    let mut prev = vec![inf; n];
    prev[0] = 0.0;
    let mut back: Vec<Vec<u32>> = Vec::with_capacity(count - 1);
    for _k in 1..count {
        let mut cur = vec![inf; n];
        let mut arg = vec![u32::MAX; n];
        for j in 1..n {
            let lo = lo_of(j);
            let (mut best, mut at) = (inf, u32::MAX);
            match &table {
                Some(t) => {
                    let row = &t[starts[j]..starts[j + 1]];
                    for (i, c) in (lo..j).zip(row) {
                        let v = prev[i] + c;
                        if v < best {
                            best = v;
                            at = i as u32;
                        }
                    }
                }
                None => {
                    for i in lo..j {
                        if prev[i] == inf {
                            continue;
                        }
                        let v = prev[i] + cost.cost(i, j);
                        if v < best {
                            best = v;
                            at = i as u32;
                        }
                    }
                }
            }
            cur[j] = best;
            arg[j] = at;
        }
        back.push(arg);
        prev = cur;
    }
    let total = prev[n - 1];
    let mut keys = vec![n - 1];
    let mut j = n - 1;
    for arg in back.iter().rev() {
        j = arg[j] as usize;
        keys.push(j);
    }
    keys.reverse();
    Ok((keys, total))
}

/// A motion's FK joint positions as a `[frames][3·joints]` curve.
pub fn position_curve(positions: &[Vec3]) -> Vec<f64> {
    positions.iter().flat_map(|p| p.iter().copied()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_cost(x: &[f64], dims: usize, i: usize, j: usize) -> f64 {
        (i..=j)
            .map(|t| {
                let u = (t - i) as f64 / (j - i) as f64;
                (0..dims)
                    .map(|d| {
                        let e = x[t * dims + d]
                            - (x[i * dims + d] + u * (x[j * dims + d] - x[i * dims + d]));
                        e * e
                    })
                    .sum::<f64>()
            })
            .sum()
    }

    fn wiggle(n: usize, dims: usize) -> Vec<f64> {
        (0..n * dims)
            .map(|k| {
                let (t, d) = ((k / dims) as f64, (k % dims) as f64);
                (0.13 * t * (1.0 + d)).sin() + 0.02 * t * d
            })
            .collect()
    }

    #[test]
    fn segment_cost_matches_brute_force() {
        let x = wiggle(40, 3);
        let c = SegmentCost::new(x.clone(), 3);
        for (i, j) in [(0, 1), (0, 2), (3, 17), (0, 39), (20, 39)] {
            let (a, b) = (c.cost(i, j), brute_cost(&x, 3, i, j));
            assert!((a - b).abs() < 1e-9 * (1.0 + b), "{i}-{j}: {a} vs {b}");
        }
    }

    /// Every subset of keyframes for a small curve: DP must find the best.
    #[test]
    fn dp_is_exact_against_exhaustive_search() {
        let n = 14;
        let x = wiggle(n, 2);
        let c = SegmentCost::new(x, 2);
        for count in 2..=6 {
            let (keys, total) = dp(&c, count, None).unwrap();
            assert_eq!(keys.len(), count);
            assert!(keys[0] == 0 && keys[count - 1] == n - 1);
            let mut best = f64::INFINITY;
            for mask in 0u32..(1 << (n - 2)) {
                if mask.count_ones() as usize != count - 2 {
                    continue;
                }
                let mut k = vec![0];
                k.extend((1..n - 1).filter(|i| mask & (1 << (i - 1)) != 0));
                k.push(n - 1);
                let s: f64 = k.windows(2).map(|w| c.cost(w[0], w[1])).sum();
                best = best.min(s);
            }
            assert!((total - best).abs() < 1e-9, "{count}: {total} vs {best}");
            let even_cost: f64 = even(n, count)
                .unwrap()
                .windows(2)
                .map(|w| c.cost(w[0], w[1]))
                .sum();
            assert!(total <= even_cost + 1e-12);
        }
    }

    #[test]
    fn selection_rules() {
        assert_eq!(even(10, 4).unwrap(), vec![0, 3, 6, 9]);
        assert_eq!(even(5, 5).unwrap(), vec![0, 1, 2, 3, 4]);
        assert!(even(5, 6).is_err() && even(5, 1).is_err() && even(1, 2).is_err());
        // Peaks at 1 (inside the guard), 5 (strong), 12 (weak): 4 keyframes
        // take 5 and 12; 5 keyframes add a midpoint in the strongest pair.
        let mut curve = vec![0.0; 20];
        curve[1] = 9.0;
        curve[5] = 3.0;
        curve[12] = 1.0;
        let p = peaks(&curve);
        assert_eq!(p, vec![1, 5, 12]);
        assert_eq!(from_peaks(&curve, &p, 4, 2).unwrap(), vec![0, 5, 12, 19]);
        assert_eq!(from_peaks(&curve, &p, 3, 2).unwrap(), vec![0, 5, 19]);
        // 0+5 → 3.0, 5+12 → 4.0, 12+19 → 1.0: the midpoint of 5 and 12.
        assert_eq!(from_peaks(&curve, &p, 5, 2).unwrap(), vec![0, 5, 8, 12, 19]);
        let mut nan = curve.clone();
        nan[3] = f64::NAN;
        assert!(from_peaks(&nan, &p, 4, 2).is_err());
        assert_eq!(beat_frames(120.0, 60.0, 100).unwrap(), vec![0, 30, 60, 90]);
        assert!(beat_frames(0.0, 60.0, 100).is_err() && beat_frames(10_000.0, 60.0, 100).is_err());
        assert_eq!(frames_per_measure(120.0, 60.0), 120.0);
    }
}
