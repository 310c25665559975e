//! Typical frames (`sampling.draws`): a candidate frame's surprise under
//! the frame model and its expectation, and the choice among candidates
//! of the one whose surprise lies nearest it (docs/RESULTS.md, "Session
//! 37: typical frames").

use super::frame::FrameConfig;

/// Of candidate frames (tokens, surprise, expected surprise), the one whose
/// surprise lies nearest its expectation, `extra(i)` added to candidate
/// `i`'s distance (the pace hold's cost; the first such on a tie), and its
/// index.
pub(super) fn most_typical(
    cands: Vec<(Vec<u32>, f64, f64)>,
    extra: impl Fn(usize) -> f64,
) -> (Vec<u32>, usize) {
    let mut best: Option<(f64, Vec<u32>, usize)> = None;
    for (i, (frame, surprise, expected)) in cands.into_iter().enumerate() {
        let off = (surprise - expected).abs() + extra(i);
        if best.as_ref().map_or(true, |b| off < b.0) {
            best = Some((off, frame, i));
        }
    }
    let (_, frame, i) = best.expect("at least one candidate");
    (frame, i)
}

/// How much a candidate frame `f` jerks after the three frames `before`
/// (oldest first): the root of the summed squares, over the angle slots,
/// of each angle's third difference in bins (the change of its
/// acceleration; every step the shorter way round), the root joint's
/// rotation (slots 0–2) counted three times: it turns every joint about
/// the body's centre. The root's travel and height are not counted. A
/// steady turn or a steady speeding-up costs nothing.
pub(super) fn frame_jerk(c: &FrameConfig, before: [&[u32]; 3], f: &[u32]) -> f64 {
    let step = |to: u32, from: u32| super::frame::short_step(to, from, c.bins);
    let [a, b, d] = before;
    let mut sum = 0.0;
    for s in (0..c.slots).filter(|&s| c.wraps(s)) {
        let j = step(f[s], d[s]) - 2 * step(d[s], b[s]) + step(b[s], a[s]);
        let w = if s < 3 { 3.0 } else { 1.0 };
        sum += w * (j * j) as f64;
    }
    sum.sqrt()
}

/// The log of Σ e^x over `x` (−∞ when empty or all −∞).
fn log_sum_exp(x: impl Iterator<Item = f32> + Clone) -> f64 {
    let m = x.clone().fold(f32::NEG_INFINITY, f32::max);
    if m == f32::NEG_INFINITY {
        return f64::NEG_INFINITY;
    }
    let z: f64 = x.map(|v| (v - m).exp() as f64).sum();
    m as f64 + z.ln()
}

/// The log-probability of class `k` under the softmax of `x`, and that
/// distribution's entropy, in one pass: with z = Σ e^{x − m} and
/// s = Σ e^{x − m} (x − m), H = ln z − s / z.
fn log_p_and_entropy(x: &[f32], k: usize) -> (f64, f64) {
    let m = x.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let (mut z, mut s) = (0.0f64, 0.0f64);
    for &v in x {
        let d = v - m;
        if d.is_finite() {
            let e = d.exp() as f64;
            z += e;
            s += e * d as f64;
        }
    }
    let lz = z.ln();
    ((x[k] - m) as f64 - lz, lz - s / z)
}

/// A drawn token's surprise (nats) under the model's unmodified
/// distribution, and that distribution's entropy.
pub(super) fn surprise_of(
    c: &FrameConfig,
    (rel, abs): (&[f32], &[f32]),
    p1: Option<u32>,
    tok: u32,
) -> (f64, f64) {
    let Some(p) = p1 else {
        let (lp, h) = log_p_and_entropy(abs, tok as usize);
        return (-lp, h);
    };
    let r0 = c.radius as i64;
    let k = c.change(Some(p), tok) as usize;
    let (lr, h) = log_p_and_entropy(&rel[..c.rel_classes()], k);
    if k != c.esc() as usize {
        return (-lr, h);
    }
    // An escape also pays the absolute head's share among the bins
    // outside the change window.
    let outside = abs
        .iter()
        .enumerate()
        .filter(|&(b, _)| (b as i64 - p as i64).abs() > r0)
        .map(|(_, &x)| x);
    (-lr - (abs[tok as usize] as f64 - log_sum_exp(outside)), h)
}

#[cfg(test)]
mod tests {
    #[test]
    fn surprise_is_the_change_heads_or_the_escapes_and_its_expectation_the_entropy() {
        let c = super::super::frame::test_config();
        let rel = vec![0.0f32; c.rel_classes()];
        let abs = vec![0.0f32; c.bins];
        let uniform_rel = (c.rel_classes() as f64).ln();
        // A change inside the window: that class's surprise.
        let (nll, h) = super::surprise_of(&c, (&rel, &abs), Some(100), 103);
        assert!((nll - uniform_rel).abs() < 1e-9 && (h - uniform_rel).abs() < 1e-9);
        // An escape: the escape class's, plus the absolute head's share among
        // the bins outside the change window (360 − 17 of them).
        let outside = (c.bins - (2 * c.radius + 1)) as f64;
        let (nll, _) = super::surprise_of(&c, (&rel, &abs), Some(100), 150);
        assert!((nll - (uniform_rel + outside.ln())).abs() < 1e-9, "{nll}");
        // No previous frame: the absolute head alone.
        let (nll, h) = super::surprise_of(&c, (&rel, &abs), None, 7);
        assert!((nll - (c.bins as f64).ln()).abs() < 1e-9 && (h - nll).abs() < 1e-9);
        // A peaked head: the likeliest change surprises less than the
        // entropy, a rare one more.
        let mut peaked = rel.clone();
        peaked[c.radius] = 5.0;
        let (likely, h) = super::surprise_of(&c, (&peaked, &abs), Some(100), 100);
        let (rare, _) = super::surprise_of(&c, (&peaked, &abs), Some(100), 104);
        assert!(likely < h && rare > h, "{likely} {h} {rare}");
    }

    #[test]
    fn jerk_is_the_third_difference_of_the_angles_root_rotation_thrice() {
        let c = super::super::frame::test_config();
        // Slots 0..39 angles (360 bins, wrapping), 39..42 the root's travel
        // and height.
        let frames = |f: &dyn Fn(usize, i64) -> i64| -> Vec<Vec<u32>> {
            (0..4)
                .map(|t| {
                    (0..c.slots)
                        .map(|s| f(s, t).rem_euclid(360) as u32)
                        .collect()
                })
                .collect()
        };
        let jerk = |fr: &[Vec<u32>]| super::frame_jerk(&c, [&fr[0], &fr[1], &fr[2]], &fr[3]);
        // Still, a steady turn (round the back: 355 → 1 → 7 → 13) and a
        // steady speeding-up (1, 3, 5 bins a frame) cost nothing.
        assert_eq!(jerk(&frames(&|_, _| 100)), 0.0);
        assert_eq!(jerk(&frames(&|_, t| 355 + 6 * t)), 0.0);
        assert_eq!(jerk(&frames(&|s, t| s as i64 + t * t)), 0.0);
        // One joint jolts 4 bins off its steady path: 4; the root's
        // rotation the same: √3 · 4; the root's travel: nothing.
        let jolt = |slot: usize| {
            let mut fr = frames(&|_, t| 50 + 2 * t);
            fr[3][slot] += 4;
            jerk(&fr)
        };
        assert!((jolt(10) - 4.0).abs() < 1e-12);
        assert!((jolt(1) - 4.0 * 3f64.sqrt()).abs() < 1e-12);
        assert_eq!(jolt(40), 0.0);
        // The squares add: two joints jolting 3 and 4 bins, 5.
        let mut fr = frames(&|_, _| 200);
        fr[3][5] += 3;
        fr[3][6] -= 4;
        assert!((jerk(&fr) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn the_kept_frame_is_the_one_nearest_its_expected_surprise() {
        // Not the likeliest (surprise 2 of 10 expected), nor the one with
        // tails at once (19): the typical one (11).
        let cands = vec![
            (vec![1], 2.0, 10.0),
            (vec![2], 19.0, 10.0),
            (vec![3], 11.0, 10.0),
            (vec![4], 8.5, 10.0),
        ];
        assert_eq!(super::most_typical(cands.clone(), |_| 0.0), (vec![3], 2));
        assert_eq!(
            super::most_typical(vec![(vec![7], 0.0, 50.0)], |_| 0.0),
            (vec![7], 0)
        );
        // An extra cost (the pace hold's) adds to the distance: the
        // second-most typical (1.5 off) wins once the first pays 1.
        let pace = |i: usize| if i == 2 { 1.0 } else { 0.0 };
        assert_eq!(super::most_typical(cands, pace), (vec![4], 3));
    }
}
