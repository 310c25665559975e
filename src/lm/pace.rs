//! Pace hold (`sampling.pace`): among a frame's candidates
//! (`sampling.draws`), a preference for the one that keeps the clip moving
//! at the pace of the motion it continues (a seed motion or a style
//! exemplar). The frame model drifts toward calm over a long clip (a run
//! slows to a walk within 1–2 s, a wave sinks to the side; its training
//! takes are short): without a hold, the clip's pace is whatever the
//! drift leaves.
//!
//! A frame's pace is four numbers, from its tokens and the two frames
//! before it: the legs' angular speed (pelvis, hips, knees, ankles: the
//! summed change of their axis-angle components, rad/s, the shorter way
//! round), the arms' (shoulders, elbows, wrists), the root's ground speed
//! (m/s) and every joint's angular acceleration (the summed change of the
//! change, rad/s²): speed without acceleration would be bought with
//! jitter. On a skeleton other than SMPL-13 every joint counts as legs.
//! The target is their mean over the seed; a candidate's cost is how far,
//! in log ratio, the mean over the last [`RECENT`] frames with it added
//! would lie from the target, summed over the four. The generator
//! adds `pace ×` that cost to each candidate's distance from typical
//! ([`super::typical`]) and keeps the least.

use super::frame::FrameConfig;
use crate::tokenize::vocab::Vocabulary;
use std::collections::VecDeque;

/// Frames the running pace is measured over (with the candidate): 0.5 s
/// at 20 fps.
pub const RECENT: usize = 10;
/// The parts a pace is measured on: legs, arms, root, acceleration.
pub const PARTS: usize = 4;
/// Floors added to both sides of each log ratio, so a still seed (or a
/// root in place) does not make every candidate infinitely far: rad/s of
/// summed joint speed (legs, arms), m/s of root speed, rad/s² of summed
/// acceleration.
const FLOOR: [f64; PARTS] = [1.0, 1.0, 0.1, 20.0];
/// Seed frames needed for a target (triples of frames measured).
const MIN_SEED: usize = 4;
/// SMPL-13's first arm joint (the left shoulder; joints before it are the
/// pelvis and legs).
const SMPL13_FIRST_ARM: usize = 7;

/// A frame's pace against the frames before it (`before`, then `prev`):
/// the legs' and the arms' summed angular speed (rad/s), the root's ground
/// speed (m/s) and the summed angular acceleration (rad/s²; 0 without
/// `before`).
pub fn frame_pace(
    v: &Vocabulary,
    c: &FrameConfig,
    before: Option<&[u32]>,
    prev: &[u32],
    cur: &[u32],
) -> [f64; PARTS] {
    let width = 2.0 * std::f64::consts::PI / c.bins as f64;
    // The signed change the shorter way round, in bins.
    let change = |a: u32, b: u32| super::frame::short_step(b, a, c.bins);
    let first_arm_slot = if v.skeleton == "smpl13" {
        3 * SMPL13_FIRST_ARM
    } else {
        usize::MAX
    };
    let (mut turn, mut acc) = ([0.0; 2], 0.0);
    for s in (0..c.slots).filter(|&s| c.wraps(s)) {
        let d = change(prev[s], cur[s]);
        turn[usize::from(s >= first_arm_slot)] += d.abs() as f64 * width;
        if let Some(b) = before {
            acc += (d - change(b[s], prev[s])).abs() as f64 * width;
        }
    }
    let (vx, vz) = v.decode_root_velocity(cur);
    [
        turn[0] * v.fps,
        turn[1] * v.fps,
        (vx * vx + vz * vz).sqrt(),
        acc * v.fps * v.fps,
    ]
}

/// The running hold: the target and the last frames' paces.
#[derive(Clone, Debug)]
pub struct Pace {
    weight: f64,
    target: [f64; PARTS],
    recent: VecDeque<[f64; PARTS]>,
}

impl Pace {
    /// The hold for continuing `seed` (whole frames of value slots), or
    /// none when the weight is 0 or the seed is too short to say its pace.
    pub fn from_seed(
        weight: f64,
        v: &Vocabulary,
        c: &FrameConfig,
        seed: &[Vec<u32>],
    ) -> Option<Pace> {
        if weight <= 0.0 || seed.len() < MIN_SEED + 2 {
            return None;
        }
        let paces: Vec<[f64; PARTS]> = seed
            .windows(3)
            .map(|w| frame_pace(v, c, Some(&w[0]), &w[1], &w[2]))
            .collect();
        let n = paces.len() as f64;
        let mut target = [0.0; PARTS];
        for (k, t) in target.iter_mut().enumerate() {
            *t = paces.iter().map(|p| p[k]).sum::<f64>() / n;
        }
        let recent = paces[paces.len().saturating_sub(RECENT - 1)..]
            .iter()
            .copied()
            .collect();
        Some(Pace {
            weight,
            target,
            recent,
        })
    }

    /// The seed's pace: legs' and arms' summed joint speed (rad/s), root
    /// speed (m/s), summed acceleration (rad/s²).
    pub fn target(&self) -> [f64; PARTS] {
        self.target
    }

    /// `weight ×` the log-ratio distance of the running pace, with a
    /// candidate of pace `p` added, from the target.
    pub fn cost(&self, p: [f64; PARTS]) -> f64 {
        let n = self.recent.len() as f64 + 1.0;
        (0..PARTS)
            .map(|k| {
                let mean = (self.recent.iter().map(|r| r[k]).sum::<f64>() + p[k]) / n;
                ((mean + FLOOR[k]) / (self.target[k] + FLOOR[k])).ln().abs()
            })
            .sum::<f64>()
            * self.weight
    }

    /// The running joint speed (legs and arms, the last frames) over the
    /// target's, each with the floor added.
    pub fn turn_ratio(&self) -> f64 {
        if self.recent.is_empty() {
            return 1.0;
        }
        let n = self.recent.len() as f64;
        let now = self.recent.iter().map(|r| r[0] + r[1]).sum::<f64>() / n;
        let floor = FLOOR[0] + FLOOR[1];
        (now + floor) / (self.target[0] + self.target[1] + floor)
    }

    /// Records the kept frame's pace.
    pub fn push(&mut self, p: [f64; PARTS]) {
        if self.recent.len() + 1 >= RECENT {
            self.recent.pop_front();
        }
        self.recent.push_back(p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slow_running_pace_prefers_the_faster_candidate_and_a_fast_one_the_slower() {
        let c = super::super::frame::test_config();
        let v = Vocabulary::new(Default::default());
        assert_eq!(
            v.bins, c.bins,
            "the test config shares the vocabulary's bins"
        );
        // A seed whose joints all turn one bin a frame, the root still.
        let seed: Vec<Vec<u32>> = (0..8u32)
            .map(|t| {
                let mut f = vec![100 + t; c.slots];
                let z = v.encode_root_velocity(0.0);
                f[c.slots - 3] = z;
                f[c.slots - 2] = z;
                f
            })
            .collect();
        let p = Pace::from_seed(1.0, &v, &c, &seed).expect("a long enough seed");
        let one = frame_pace(&v, &c, Some(&seed[0]), &seed[1], &seed[2]);
        // SMPL-13: 7 leg joints (pelvis, hips, knees, ankles), 6 arm joints.
        let per_bin = 2.0 * std::f64::consts::PI / c.bins as f64 * v.fps;
        let (legs, arms) = (21.0 * per_bin, 18.0 * per_bin);
        assert!(
            (one[0] - legs).abs() < 1e-9 && (one[1] - arms).abs() < 1e-9,
            "{one:?}"
        );
        assert!(one[2].abs() < 0.2, "root speed of a still root: {one:?}");
        assert!(
            one[3].abs() < 1e-12,
            "a steady turn does not accelerate: {one:?}"
        );
        assert!((p.target()[0] - legs).abs() < 1e-9);
        // Only the arms turning: the legs' pace is 0.
        let mut arms_only = seed[0].clone();
        for t in arms_only[21..39].iter_mut() {
            *t += 2;
        }
        let a = frame_pace(&v, &c, None, &seed[0], &arms_only);
        assert!(
            a[0].abs() < 1e-12 && (a[1] - 2.0 * arms).abs() < 1e-9,
            "{a:?}"
        );
        // From a still frame to a turning one: the arms' change of change,
        // and the shorter way round (bin 0 after 359 is one bin on).
        let b = frame_pace(&v, &c, Some(&seed[0]), &seed[0], &arms_only);
        assert!((b[3] - 2.0 * arms * v.fps).abs() < 1e-9, "{b:?}");
        let (mut f0, mut f1) = (vec![358u32; c.slots], vec![359u32; c.slots]);
        let mut f2 = vec![0u32; c.slots];
        for f in [&mut f0, &mut f1, &mut f2] {
            f[c.slots - 3] = 180;
            f[c.slots - 2] = 180;
        }
        let w = frame_pace(&v, &c, Some(&f0), &f1, &f2);
        assert!((w[0] - legs).abs() < 1e-9 && w[3].abs() < 1e-12, "{w:?}");
        // At the seed's pace the cost is least; slower or faster costs more.
        assert!(p.cost(one) < 1e-9);
        let at = |l: f64| [l, one[1], one[2], one[3]];
        assert!(p.cost(at(0.0)) > p.cost(at(legs * 0.5)));
        assert!(p.cost(at(legs * 3.0)) > p.cost(at(legs * 1.5)));
        // After slow frames, a faster-than-target candidate pulls the
        // running pace back and costs less than another slow one.
        let mut slow = p.clone();
        for _ in 0..RECENT {
            slow.push(at(0.0));
        }
        assert!(slow.cost(at(legs * 2.0)) < slow.cost(at(0.0)));
        // The running joint speed against the seed's (what sampling.ease
        // eases the posture pull by): 1 at the seed's pace, (floor) over
        // (seed + floor) when still, above 1 faster.
        let mut r = p.clone();
        for _ in 0..RECENT {
            r.push(one);
        }
        assert!((r.turn_ratio() - 1.0).abs() < 1e-9);
        let floor = FLOOR[0] + FLOOR[1];
        let still = [0.0, 0.0, one[2], one[3]];
        for _ in 0..RECENT {
            r.push(still);
        }
        assert!((r.turn_ratio() - floor / (legs + arms + floor)).abs() < 1e-9);
        r.push([2.0 * legs, 2.0 * arms, 0.0, 0.0]);
        assert!(r.turn_ratio() > floor / (legs + arms + floor));
        // Weight 0, or a seed too short, makes no hold.
        assert!(Pace::from_seed(0.0, &v, &c, &seed).is_none());
        assert!(Pace::from_seed(1.0, &v, &c, &seed[..MIN_SEED + 1]).is_none());
    }
}
