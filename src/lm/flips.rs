//! Half-turn flips finished. Near a half turn (θ = π) a joint's axis-angle
//! slots meet the edge of their range: a rotation turning on past π is
//! written as its twin (2π − θ about the opposite axis), every component's
//! sign changed. The real takes do that in one frame; a drawn frame can
//! instead wrap one component round the ±π edge (a step of a bin or two)
//! while the others keep their sign, a rotation tens of degrees from both
//! the joint's last pose and the twin it was heading for. Bandai holds the
//! right hip near a half turn in 82 % of its style frames; drawn clips
//! jumped it more than 35° in a frame 5.5 times in 1,000 frames, the real
//! takes never (docs/RESULTS.md, "Session 45: half-turn flips finished").
//!
//! [`finish`] sees each joint of a drawn frame against the frame before:
//! where some of its slots wrapped round the edge and the others did not,
//! it tries the others' signs changed too (the twin the wrap was heading
//! for) and keeps whichever rotation lies nearer the joint's last one.

use super::frame::{short_step, slot_wraps};
use crate::motion::rotation::{axis_angle_to_quat, geodesic_quat as apart};
use crate::tokenize::UniformBins;

/// Finishes the half-turn flips of `frame` (a frame's tokens, `slots`
/// value slots first) against `p1`, the frame before, for every joint
/// whose three slots are angles and none of them `forced` (a joint
/// prompt's slots stay as asked). Of the drawn joint, its twin (the other
/// slots' signs changed too) and the drawn joint held at the edge (the
/// wrapped slots kept on `p1`'s side of it), the rotation nearest the
/// joint's last one is kept; the twin only where every slot stays within
/// `max_jump` of `p1` (0: no limit), a cap the request set on slots.
/// Returns how many joints were changed.
pub fn finish(
    frame: &mut [u32],
    p1: &[u32],
    forced: &[Option<u32>],
    (slots, bins, max_jump): (usize, usize, u32),
) -> usize {
    let angles = UniformBins::angles(bins);
    let rot = |f: &[u32]| axis_angle_to_quat([0, 1, 2].map(|i| angles.decode(f[i])));
    let half = bins as i64 / 2;
    let top = bins as u32 - 1;
    let within = |t: &[u32; 3], s: usize| {
        max_jump == 0
            || (0..3).all(|i| short_step(t[i], p1[s + i], bins).unsigned_abs() <= max_jump as u64)
    };
    let mut changed = 0;
    for j in 0..slots / 3 {
        let s = 3 * j;
        if !(s..s + 3).all(|k| slot_wraps(k, slots))
            || (s..s + 3).any(|k| forced.get(k).is_some_and(|f| f.is_some()))
        {
            continue;
        }
        // The slots that went round the edge: their raw step is over half
        // the range (the short way round is the other way).
        let wrapped = [s, s + 1, s + 2].map(|k| (frame[k] as i64 - p1[k] as i64).abs() > half);
        if !wrapped.iter().any(|&w| w) || wrapped.iter().all(|&w| w) {
            continue;
        }
        let drawn = [frame[s], frame[s + 1], frame[s + 2]];
        // Bin b is the mirror of bins − 1 − b about 0.
        let twin = [0, 1, 2].map(|i| if wrapped[i] { drawn[i] } else { top - drawn[i] });
        let held = [0, 1, 2].map(|i| match (wrapped[i], p1[s + i] as i64 > half) {
            (false, _) => drawn[i],
            (true, true) => top,
            (true, false) => 0,
        });
        let q1 = rot(&p1[s..s + 3]);
        let mut best = (apart(q1, rot(&drawn)), drawn);
        for t in [twin, held] {
            let d = apart(q1, rot(&t));
            if d < best.0 && within(&t, s) {
                best = (d, t);
            }
        }
        if best.1 != drawn {
            frame[s..s + 3].copy_from_slice(&best.1);
            changed += 1;
        }
    }
    changed
}

#[cfg(test)]
mod tests {
    use super::*;

    // 9 slots as in matching's tests: 0–2 the root, 3–5 a joint, 6–7 the
    // root's ground velocity, 8 its height; 360 bins.
    fn frame(root: [f64; 3], joint: [f64; 3]) -> Vec<u32> {
        let a = UniformBins::angles(360);
        let mut f: Vec<u32> = root.iter().chain(&joint).map(|&v| a.encode(v)).collect();
        f.extend([180, 180, 100]);
        f
    }

    fn turn(a: &[u32], b: &[u32]) -> f64 {
        let angles = UniformBins::angles(360);
        let rot = |f: &[u32]| axis_angle_to_quat([0, 1, 2].map(|i| angles.decode(f[i])));
        apart(rot(a), rot(b)).to_degrees()
    }

    #[test]
    fn a_wrap_of_one_slot_becomes_the_whole_flip() {
        // The joint at 176° about (0.3, 1, 0.2)-ish: y near +π, x and z
        // well off zero, turning on past the half turn.
        let p1 = frame([0.0; 3], [0.35, 3.05, 0.25]);
        // Drawn: y went round the edge (−3.12), x and z kept their sign.
        let mut f = frame([0.0; 3], [0.35, -3.12, 0.25]);
        let before = turn(&p1[3..6], &f[3..6]);
        assert!(before > 20.0, "a partial flip is a big turn: {before}");
        assert_eq!(finish(&mut f, &p1, &[None; 9], (9, 360, 0)), 1);
        let after = turn(&p1[3..6], &f[3..6]);
        assert!(after < 8.0, "finished: {after}° from the last pose");
        // x and z changed sign, y kept its wrap.
        let a = UniformBins::angles(360);
        assert!(a.decode(f[3]) < 0.0 && a.decode(f[5]) < 0.0 && a.decode(f[4]) < -3.0);
        // The root (0–2) and the other slots are left alone.
        assert_eq!(f[..3], p1[..3]);
        assert_eq!(f[6..], p1[6..]);
    }

    #[test]
    fn ordinary_steps_and_prompts_are_left_alone() {
        let p1 = frame([0.1, 0.2, 0.0], [0.35, 3.05, 0.25]);
        // A small step with no wrap.
        let mut f = frame([0.1, 0.2, 0.0], [0.37, 3.08, 0.22]);
        let g = f.clone();
        assert_eq!(finish(&mut f, &p1, &[None; 9], (9, 360, 0)), 0);
        assert_eq!(f, g);
        // A partial flip on a prompted joint stays as asked.
        let mut f = frame([0.1, 0.2, 0.0], [0.35, -3.12, 0.25]);
        let g = f.clone();
        let mut forced = [None; 9];
        forced[4] = Some(g[4]);
        assert_eq!(finish(&mut f, &p1, &forced, (9, 360, 0)), 0);
        assert_eq!(f, g);
    }

    #[test]
    fn a_cap_on_slots_holds_the_joint_at_the_edge_instead() {
        // The same partial flip under max_jump 12: the twin would move x
        // and z by 40 and 29 bins, so the wrapped y is held on p1's side
        // of the edge instead; every slot within the cap, the pose near.
        let p1 = frame([0.0; 3], [0.35, 3.05, 0.25]);
        let mut f = frame([0.0; 3], [0.35, -3.12, 0.25]);
        assert_eq!(finish(&mut f, &p1, &[None; 9], (9, 360, 12)), 1);
        assert_eq!(f[4], 359);
        for k in 0..9 {
            assert!(short_step(f[k], p1[k], 360).abs() <= 12, "slot {k}");
        }
        assert!(turn(&p1[3..6], &f[3..6]) < 8.0);
    }
}
