//! In-between reconstruction from keyframes (thesis 001 §3.5, SPEC §6).
//!
//! - [`slerp`]: root translation lerped, every joint's quaternion SLERPed.
//! - [`bezier`]: one cubic Bézier per segment and channel (channels: each
//!   joint's axis-angle made continuous over time, plus the root
//!   translation); P0 and P3 are the keyframes, P1 and P2 are the linear
//!   least-squares fit to the original in-betweens (the thesis used
//!   Levenberg–Marquardt on the same, linear, problem).
//! - [`BezierOffsets`]: the thesis's fair variant — P1 and P2 are placed at
//!   the thirds of the keyframe chord plus per-channel offsets averaged over
//!   the segments of a training set, so no ground truth of the clip is used.

use super::bad;
use crate::motion::rotation::{axis_angle_to_quat, lerp3, quat_to_axis_angle, slerp as qslerp};
use crate::motion::{Motion, MotionError};
use crate::tokenize::{unwrap_joints, Series};
use serde::{Deserialize, Serialize};

fn check_keys(m: &Motion, keys: &[usize]) -> Result<(), MotionError> {
    let n = m.frames();
    if keys.len() < 2 || keys[0] != 0 || *keys.last().unwrap_or(&0) != n.saturating_sub(1) {
        return Err(bad(
            "keyframes",
            format!(
                "need the first (0) and last ({}) frames among at least 2 keyframes",
                n.saturating_sub(1)
            ),
        ));
    }
    if keys.windows(2).any(|w| w[1] <= w[0]) {
        return Err(bad("keyframes", "must be strictly increasing".into()));
    }
    Ok(())
}

/// Lerp the root, SLERP every joint between consecutive keyframes.
pub fn slerp(m: &Motion, keys: &[usize]) -> Result<Motion, MotionError> {
    check_keys(m, keys)?;
    let j = m.joints();
    let mut rots = m.rotations.clone();
    let mut trans = m.trans.clone();
    for w in keys.windows(2) {
        let (a, b) = (w[0], w[1]);
        for t in a + 1..b {
            let u = (t - a) as f64 / (b - a) as f64;
            trans[t] = lerp3(m.trans[a], m.trans[b], u);
            for k in 0..j {
                let q = qslerp(
                    axis_angle_to_quat(m.rotations[a * j + k]),
                    axis_angle_to_quat(m.rotations[b * j + k]),
                    u,
                );
                rots[t * j + k] = quat_to_axis_angle(q);
            }
        }
    }
    Ok(m.with_data(trans, rots))
}

/// The Bézier channels: continuous axis-angle per joint, then the root
/// translation. `[frames][3·joints + 3]`.
fn channels(m: &Motion) -> Series {
    let j = m.joints();
    let rot: Vec<f64> = m.rotations.iter().flat_map(|r| r.iter().copied()).collect();
    let mut s = Series::new(3 * j, rot).expect("validated motion");
    unwrap_joints(&mut s);
    let c = 3 * j + 3;
    let mut data = Vec::with_capacity(m.frames() * c);
    for t in 0..m.frames() {
        data.extend_from_slice(s.row(t));
        data.extend_from_slice(&m.trans[t]);
    }
    Series { channels: c, data }
}

fn from_channels(m: &Motion, x: &Series) -> Motion {
    let j = m.joints();
    let rots = (0..m.frames() * j)
        .map(|i| {
            let (t, k) = (i / j, i % j);
            let r = x.row(t);
            [r[3 * k], r[3 * k + 1], r[3 * k + 2]]
        })
        .collect();
    let trans = (0..m.frames())
        .map(|t| {
            let r = x.row(t);
            [r[3 * j], r[3 * j + 1], r[3 * j + 2]]
        })
        .collect();
    m.with_data(trans, rots)
}

fn bern(u: f64) -> [f64; 4] {
    let v = 1.0 - u;
    [v * v * v, 3.0 * u * v * v, 3.0 * u * u * v, u * u * u]
}

/// Least-squares inner control points of one segment and channel.
fn fit_segment(x: &Series, a: usize, b: usize, c: usize) -> (f64, f64) {
    let (p0, p3) = (x.row(a)[c], x.row(b)[c]);
    let (mut saa, mut sab, mut sbb, mut sar, mut sbr) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for t in a + 1..b {
        let w = bern((t - a) as f64 / (b - a) as f64);
        let r = x.row(t)[c] - w[0] * p0 - w[3] * p3;
        saa += w[1] * w[1];
        sab += w[1] * w[2];
        sbb += w[2] * w[2];
        sar += w[1] * r;
        sbr += w[2] * r;
    }
    let det = saa * sbb - sab * sab;
    if det.abs() > 1e-12 * (saa * sbb).max(1e-300) {
        ((sbb * sar - sab * sbr) / det, (saa * sbr - sab * sar) / det)
    } else if saa + sbb > 0.0 {
        // One in-between: P1 = P2 = p with (w1 + w2) p = r.
        let p = (sar + sbr) / (saa + 2.0 * sab + sbb);
        (p, p)
    } else {
        ((2.0 * p0 + p3) / 3.0, (p0 + 2.0 * p3) / 3.0)
    }
}

fn render(
    m: &Motion,
    x: &Series,
    keys: &[usize],
    ctrl: impl Fn(usize, usize, usize) -> (f64, f64),
) -> Motion {
    let mut out = x.clone();
    let ch = x.channels;
    for w in keys.windows(2) {
        let (a, b) = (w[0], w[1]);
        for c in 0..ch {
            let (p1, p2) = ctrl(a, b, c);
            let (p0, p3) = (x.row(a)[c], x.row(b)[c]);
            for t in a + 1..b {
                let bw = bern((t - a) as f64 / (b - a) as f64);
                out.data[t * ch + c] = bw[0] * p0 + bw[1] * p1 + bw[2] * p2 + bw[3] * p3;
            }
        }
    }
    from_channels(m, &out)
}

/// Cubic Bézier per segment with least-squares inner control points (uses
/// the clip's own in-betweens: a compression, not a prediction).
pub fn bezier(m: &Motion, keys: &[usize]) -> Result<Motion, MotionError> {
    check_keys(m, keys)?;
    let x = channels(m);
    Ok(render(m, &x, keys, |a, b, c| fit_segment(&x, a, b, c)))
}

/// Per-channel control-point offsets from the chord's thirds, averaged over
/// training segments: P1 = (2P0 + P3)/3 + d1, P2 = (P0 + 2P3)/3 + d2.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BezierOffsets {
    pub d1: Vec<f64>,
    pub d2: Vec<f64>,
    pub segments: usize,
}

impl BezierOffsets {
    /// Average the least-squares offsets of every segment of the training
    /// clips (all on the same skeleton).
    pub fn fit(train: &[(&Motion, Vec<usize>)]) -> Result<BezierOffsets, MotionError> {
        let mut d1: Vec<f64> = vec![];
        let mut d2: Vec<f64> = vec![];
        let mut segments = 0;
        for (m, keys) in train {
            check_keys(m, keys)?;
            let x = channels(m);
            if d1.is_empty() {
                d1 = vec![0.0; x.channels];
                d2 = vec![0.0; x.channels];
            } else if d1.len() != x.channels {
                return Err(bad("training", "clips on different skeletons".into()));
            }
            for w in keys.windows(2) {
                if w[1] - w[0] < 2 {
                    continue;
                }
                segments += 1;
                for c in 0..x.channels {
                    let (p0, p3) = (x.row(w[0])[c], x.row(w[1])[c]);
                    let (p1, p2) = fit_segment(&x, w[0], w[1], c);
                    d1[c] += p1 - (2.0 * p0 + p3) / 3.0;
                    d2[c] += p2 - (p0 + 2.0 * p3) / 3.0;
                }
            }
        }
        if segments == 0 {
            return Err(bad("training", "no segment with in-betweens to fit".into()));
        }
        d1.iter_mut()
            .chain(d2.iter_mut())
            .for_each(|v| *v /= segments as f64);
        Ok(BezierOffsets { d1, d2, segments })
    }

    pub fn apply(&self, m: &Motion, keys: &[usize]) -> Result<Motion, MotionError> {
        check_keys(m, keys)?;
        let x = channels(m);
        if x.channels != self.d1.len() {
            return Err(bad(
                "skeleton",
                format!(
                    "offsets were fitted on {} channels, the clip has {}",
                    self.d1.len(),
                    x.channels
                ),
            ));
        }
        Ok(render(m, &x, keys, |a, b, c| {
            let (p0, p3) = (x.row(a)[c], x.row(b)[c]);
            (
                (2.0 * p0 + p3) / 3.0 + self.d1[c],
                (p0 + 2.0 * p3) / 3.0 + self.d2[c],
            )
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{Labels, Skeleton};

    /// SMPL-13 clip whose elbow follows a cubic in time and whose root moves
    /// on a straight line at constant speed.
    fn cubic_clip(n: usize) -> Motion {
        let sk = Skeleton::smpl13();
        let mut rots = vec![[0.0; 3]; n * 13];
        for t in 0..n {
            let u = t as f64 / (n - 1) as f64;
            rots[t * 13 + 9] = [0.0, 0.0, 1.2 * u * u * u - 0.9 * u * u + 0.4 * u];
        }
        let trans = (0..n).map(|t| [t as f64 * 0.01, 0.0, 0.0]).collect();
        Motion::new("cubic", 60.0, sk, trans, rots, Labels::new()).unwrap()
    }

    #[test]
    fn keyframes_are_kept_and_a_cubic_is_recovered_exactly() {
        let m = cubic_clip(61);
        let keys = vec![0, 60];
        let b = bezier(&m, &keys).unwrap();
        for t in 0..61 {
            assert!(
                (b.rotations[t * 13 + 9][2] - m.rotations[t * 13 + 9][2]).abs() < 1e-9,
                "{t}"
            );
            assert!((b.trans[t][0] - m.trans[t][0]).abs() < 1e-12);
        }
        // SLERP keeps keyframes and moves the root linearly.
        let s = slerp(&m, &[0, 20, 60]).unwrap();
        for &k in &[0, 20, 60] {
            assert_eq!(s.rotations[k * 13 + 9], m.rotations[k * 13 + 9]);
        }
        assert!((s.trans[40][0] - 0.4).abs() < 1e-12);
        // The cubic is not linear: SLERP errs in between, Bézier does not.
        assert!((s.rotations[10 * 13 + 9][2] - m.rotations[10 * 13 + 9][2]).abs() > 1e-3);
    }

    #[test]
    fn averaged_offsets_reproduce_a_shared_shape() {
        // Train and test clips share the same cubic: the averaged offsets of
        // one segment fit the other exactly.
        let m = cubic_clip(61);
        let off = BezierOffsets::fit(&[(&m, vec![0, 60])]).unwrap();
        assert_eq!(off.segments, 1);
        let r = off.apply(&m, &[0, 60]).unwrap();
        for t in 0..61 {
            assert!((r.rotations[t * 13 + 9][2] - m.rotations[t * 13 + 9][2]).abs() < 1e-9);
        }
        assert!(off.apply(&m, &[0, 30]).is_err());
        assert!(bezier(&m, &[0, 30, 30, 60]).is_err());
        assert!(slerp(&m, &[5, 60]).is_err());
    }
}
