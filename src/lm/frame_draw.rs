//! One slot's draw for the frame generator: the model's change head (or
//! an escape to its absolute head), with the posture pull, `max_jump` and
//! `keep_near` applied ([`draw`]).

use super::frame::FrameConfig;
use super::sampling::Sampling;
use rand::rngs::StdRng;

/// A slot's token: a change from the previous frame's token (or an
/// escape to the absolute head, with the change window masked out); the
/// absolute head alone when there is no previous frame. `wraps`: the
/// slot is an angle, whose bins meet round the back (max_jump measures
/// the shorter way round); else (the root's velocity and height) a jump
/// is the plain distance: before session 21 the height could wrap from
/// the floor to two metres up in one frame.
pub(super) fn draw(
    sampling: &Sampling,
    rng: &mut StdRng,
    c: &FrameConfig,
    (rel, abs): (&[f32], &[f32]),
    pull: Option<&[f32]>,
    p1: Option<u32>,
    wraps: bool,
) -> u32 {
    // The posture pull: each bin's offset, added to the absolute head (only
    // built when drawn from: the first frame, or an escape) and to the
    // change that reaches the bin.
    let abs_pulled = || -> Vec<f32> {
        match pull {
            Some(u) => abs.iter().zip(u).map(|(a, b)| a + b).collect(),
            None => abs.to_vec(),
        }
    };
    let Some(p) = p1 else {
        return sampling.draw(&abs_pulled(), rng) as u32;
    };
    let bins = c.bins as i64;
    let r0 = c.radius as i64;
    // max_jump: a bin the slot may reach (an angle's the shorter way round). The
    // change window's targets lie within r0 bins, so they need masking
    // only under a limit below r0; the escape only when no bin outside the
    // window is reachable.
    let jump = sampling.max_jump as i64;
    let reach = |b: i64| within_jump(b, p as i64, jump, bins, wraps);
    let outside = |b: i64| (b - p as i64).abs() > r0 && reach(b);
    let moved;
    let rel = match pull {
        Some(u) => {
            let mut r = rel.to_vec();
            for (i, x) in r[..=2 * r0 as usize].iter_mut().enumerate() {
                *x += u[(p as i64 + i as i64 - r0).clamp(0, bins - 1) as usize];
            }
            // The escape is pulled too: by its bins' offsets averaged under
            // the absolute head's distribution over them (the bins it draws
            // from), so the product of the model and the pull is one
            // distribution over bins. Left unpulled, a slot away from its
            // posture, whose every change the pull lowers, escaped more
            // often and jumped (docs/RESULTS.md, "Session 40").
            r[c.esc() as usize] += escape_pull(abs, u, outside);
            moved = r;
            &moved[..]
        }
        None => rel,
    };
    let near = sampling.keep_near as i64;
    let can_escape = escapable(p as i64, r0, jump, bins, wraps);
    let mut limited;
    let rel = if jump > 0 && (jump < r0 || !can_escape) {
        limited = rel.to_vec();
        for (i, x) in limited[..=2 * r0 as usize].iter_mut().enumerate() {
            if !reach(p as i64 + i as i64 - r0) {
                *x = f32::NEG_INFINITY;
            }
        }
        if !can_escape {
            limited[c.esc() as usize] = f32::NEG_INFINITY;
        }
        &limited[..]
    } else {
        rel
    };
    // The small changes stay drawable however the tail is cut (keep_near).
    let k = sampling.draw_keeping(rel, rng, |i| {
        near > 0 && i != c.esc() as usize && (i as i64 - r0).abs() <= near
    }) as u32;
    if let Some(b) = c.apply_change(p, k) {
        return b;
    }
    let mut masked = abs_pulled();
    for (b, x) in masked.iter_mut().enumerate() {
        if !outside(b as i64) {
            *x = f32::NEG_INFINITY;
        }
    }
    sampling.draw(&masked, rng) as u32
}

/// Whether bin `b` is within `jump` bins of `p` (0: no limit), the
/// shorter way round for a slot that `wraps`.
fn within_jump(b: i64, p: i64, jump: i64, bins: i64, wraps: bool) -> bool {
    let d = (b - p).abs();
    jump == 0 || if wraps { d.min(bins - d) } else { d } <= jump
}

/// Whether [`draw`] can read bin `b`'s pull offset for a slot whose last
/// bin was `p`: in the change window (within `r0`), or where an escape
/// may land (within `jump`; anywhere when it is 0).
pub(super) fn reads_bin(b: i64, p: i64, (r0, jump): (i64, i64), bins: i64, wraps: bool) -> bool {
    (b - p).abs() <= r0 || within_jump(b, p, jump, bins, wraps)
}

/// The pull's offset to the escape class: ln Σ q(b) e^{u(b)} over the bins
/// an escape may land on (`outside`), q the absolute head's distribution
/// over them (0 when there are none).
fn escape_pull(abs: &[f32], u: &[f32], outside: impl Fn(i64) -> bool) -> f32 {
    let m = abs
        .iter()
        .enumerate()
        .filter(|&(b, _)| outside(b as i64))
        .fold(f32::NEG_INFINITY, |a, (_, &x)| a.max(x));
    if m == f32::NEG_INFINITY {
        return 0.0;
    }
    let (mut z, mut zu) = (0.0f64, 0.0f64);
    for (b, (&x, &o)) in abs.iter().zip(u).enumerate() {
        if outside(b as i64) {
            let q = ((x - m) as f64).exp();
            z += q;
            zu += q * (o as f64).exp();
        }
    }
    if zu > 0.0 {
        (zu / z).ln() as f32
    } else {
        f32::NEG_INFINITY
    }
}

/// Whether a slot at bin `p` can escape its change window (a bin more than
/// `r0` away) and still move at most `jump` bins (`jump` > 0), the
/// shorter way round where the slot `wraps`: a bin just outside the
/// window when `jump` > `r0`, else only a wrap-around one, at least
/// `bins − jump` away.
fn escapable(p: i64, r0: i64, jump: i64, bins: i64, wraps: bool) -> bool {
    let far = p.max(bins - 1 - p);
    far > r0 && (jump > r0 || (wraps && far >= bins - jump))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn max_jump_wraps_round_for_angles_only() {
        // Every escape's mass on bin 358, the slot at bin 2: 4 bins away
        // the short way round for an angle, 356 for the root's height.
        let c = crate::lm::frame::test_config();
        let mut rel = vec![f32::NEG_INFINITY; c.rel_classes()];
        rel[c.esc() as usize] = 0.0;
        let mut abs = vec![-10.0f32; c.bins];
        abs[358] = 10.0;
        let sampling = Sampling {
            temperature: 1.0,
            max_jump: 48,
            ..Sampling::default()
        };
        let mut rng = StdRng::seed_from_u64(1);
        let (angle, height) = (0, c.slots - 1);
        assert!(c.wraps(angle) && !c.wraps(height) && !c.wraps(c.slots - 3));
        let mut from_bin_2 = |slot: usize| {
            draw(
                &sampling,
                &mut rng,
                &c,
                (&rel, &abs),
                None,
                Some(2),
                c.wraps(slot),
            )
        };
        for _ in 0..50 {
            let a = from_bin_2(angle);
            assert_eq!(a, 358, "an angle may wrap round");
            let h = from_bin_2(height);
            assert!(h <= 2 + 48, "the height jumped from bin 2 to {h}");
        }
    }

    #[test]
    fn the_pull_weighs_the_escape_by_the_bins_it_lands_on() {
        // The model: every change and the escape alike (18 classes), the
        // absolute head flat. The pull leaves two bins, one step up from
        // the slot (bin 101) and one far (bin 300), and all but rules out
        // the rest. The product of the two puts 1/18 on bin 101 and
        // 1/18 · 1/343 on bin 300: an escape about one draw in 344. Left
        // unpulled, the escape would take half the draws.
        let c = crate::lm::frame::test_config();
        let rel = vec![0.0f32; c.rel_classes()];
        let abs = vec![0.0f32; c.bins];
        let mut u = vec![-50.0f32; c.bins];
        u[101] = 0.0;
        u[300] = 0.0;
        let sampling = Sampling {
            temperature: 1.0,
            ..Sampling::default()
        };
        let mut rng = StdRng::seed_from_u64(3);
        let n = 4000;
        let mut far = 0;
        for _ in 0..n {
            match draw(
                &sampling,
                &mut rng,
                &c,
                (&rel, &abs),
                Some(&u),
                Some(100),
                true,
            ) {
                101 => {}
                300 => far += 1,
                b => panic!("drew bin {b}, which the pull all but rules out"),
            }
        }
        assert!(far > 0 && far < n / 100, "{far} of {n} escaped");
        // The escape's offset itself: the mean of e^u under the head over
        // the bins it may land on.
        let outside = |b: i64| (b - 100).abs() > c.radius as i64;
        let half = vec![0.5f32.ln(); c.bins];
        assert!((escape_pull(&abs, &half, outside) - 0.5f32.ln()).abs() < 1e-6);
        let one = escape_pull(&abs, &u, outside);
        let want = (1.0f64 / (c.bins - 2 * c.radius - 1) as f64).ln() as f32;
        assert!((one - want).abs() < 1e-4, "{one} against {want}");
        assert_eq!(escape_pull(&abs, &u, |_| false), 0.0);
    }

    #[test]
    fn escapable_matches_a_search_over_every_bin() {
        for bins in [10i64, 17, 360] {
            for r0 in [1i64, 3, 4] {
                for jump in 1..=bins / 2 {
                    for p in 0..bins {
                        for wraps in [true, false] {
                            let search = (0..bins).any(|b| {
                                let d = (b - p).abs();
                                d > r0 && if wraps { d.min(bins - d) } else { d } <= jump
                            });
                            assert_eq!(
                                super::escapable(p, r0, jump, bins, wraps),
                                search,
                                "bins {bins} r0 {r0} jump {jump} p {p} wraps {wraps}"
                            );
                        }
                    }
                }
            }
        }
    }
}
