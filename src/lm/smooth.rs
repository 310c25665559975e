//! Smoothing a generated clip after it is drawn: every joint's rotation
//! averaged over a Gaussian window of frames (as unit quaternions, each
//! kept in the previous frame's hemisphere, so a rotation near ±π does not
//! average with its own antipode), the root's velocity and height over
//! the same window, then quantised back into the vocabulary's bins.
//!
//! A post-filter, not a sampling setting: the model never reads the
//! smoothed frames, and the clip's first and last 4σ frames see a
//! reflected window.

use crate::keyframes::metrics::gaussian_smooth;
use crate::motion::rotation::{axis_angle_to_quat, quat_normalize, quat_to_axis_angle, wrap_axis_angle};
use crate::tokenize::vocab::Vocabulary;

/// The frames of `tokens` (whole frames of `vocab.frame_len()` tokens, no
/// prefix; a trailing partial frame is left as it is) with every value
/// slot smoothed by a Gaussian of `sigma` frames. `sigma` ≤ 0 returns the
/// tokens unchanged.
pub fn smooth_frames(vocab: &Vocabulary, tokens: &[u32], sigma: f64) -> Vec<u32> {
    let fl = vocab.frame_len();
    let frames = tokens.len() / fl;
    let mut out = tokens.to_vec();
    if sigma <= 0.0 || frames < 2 {
        return out;
    }
    let nj = vocab.joints.len();
    let ab = vocab.angle_bins();
    for j in 0..nj {
        let mut comp = [
            Vec::with_capacity(frames),
            Vec::with_capacity(frames),
            Vec::with_capacity(frames),
            Vec::with_capacity(frames),
        ];
        let mut prev: Option<[f64; 4]> = None;
        for f in 0..frames {
            let s = f * fl + 3 * j;
            let aa = [ab.decode(tokens[s]), ab.decode(tokens[s + 1]), ab.decode(tokens[s + 2])];
            let mut q = axis_angle_to_quat(aa);
            if let Some(p) = prev {
                if p.iter().zip(&q).map(|(a, b)| a * b).sum::<f64>() < 0.0 {
                    q = q.map(|c| -c);
                }
            }
            prev = Some(q);
            for (c, v) in comp.iter_mut().zip(q) {
                c.push(v);
            }
        }
        let sm: Vec<Vec<f64>> = comp.iter().map(|c| gaussian_smooth(c, sigma)).collect();
        for f in 0..frames {
            let q = quat_normalize([sm[0][f], sm[1][f], sm[2][f], sm[3][f]]);
            let aa = wrap_axis_angle(quat_to_axis_angle(q));
            let s = f * fl + 3 * j;
            for (k, v) in aa.iter().enumerate() {
                out[s + k] = ab.encode(*v);
            }
        }
    }
    // The root's velocity and height: uniform bins, so the bin index is
    // an affine function of the value and can be averaged directly.
    let top = (vocab.bins - 1) as f64;
    for slot in 3 * nj..fl - 1 {
        let x: Vec<f64> = (0..frames).map(|f| tokens[f * fl + slot] as f64).collect();
        for (f, v) in gaussian_smooth(&x, sigma).into_iter().enumerate() {
            out[f * fl + slot] = v.round().clamp(0.0, top) as u32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn vocab() -> Vocabulary {
        Vocabulary::new(BTreeMap::new())
    }

    /// A clip whose every slot sits on one bin, with one frame knocked
    /// away, returns to that bin everywhere but near the knock, and the
    /// knock shrinks.
    #[test]
    fn a_one_frame_spike_is_spread_and_shrunk() {
        let v = vocab();
        let fl = v.frame_len();
        let ab = v.angle_bins();
        let rest = ab.encode(0.3);
        let mut t = Vec::new();
        for _ in 0..40 {
            let mut f = vec![rest; fl - 1];
            f.push(v.sep());
            t.extend(f);
        }
        let spike = ab.encode(0.9);
        t[20 * fl + 4] = spike;
        let s = smooth_frames(&v, &t, 1.5);
        assert_eq!(s.len(), t.len());
        for f in 0..40 {
            assert_eq!(s[f * fl + fl - 1], v.sep(), "separator kept");
            assert_eq!(s[f * fl], rest, "untouched slot stays");
        }
        let peak = ab.decode(s[20 * fl + 4]);
        assert!(peak > 0.3 && peak < 0.5, "spike shrunk to {peak}");
        assert_eq!(s[2 * fl + 4], rest);
    }

    /// A joint turning steadily through ±π (axis-angle wraps to the other
    /// side) is not pulled through zero by the average.
    #[test]
    fn rotations_through_pi_average_on_the_short_way() {
        let v = vocab();
        let fl = v.frame_len();
        let ab = v.angle_bins();
        let mut t = Vec::new();
        for f in 0..30 {
            let a = 3.0 + 0.02 * f as f64; // crosses π at f ≈ 7
            let aa = wrap_axis_angle([0.0, a, 0.0]);
            let mut fr = vec![ab.encode(0.0); fl - 1];
            fr[0] = ab.encode(aa[0]);
            fr[1] = ab.encode(aa[1]);
            fr[2] = ab.encode(aa[2]);
            fr.push(v.sep());
            t.extend(fr);
        }
        let s = smooth_frames(&v, &t, 2.0);
        for f in 0..30 {
            let y = ab.decode(s[f * fl + 1]);
            assert!(y.abs() > 2.8, "frame {f}: y {y} fell toward zero");
        }
    }
}
