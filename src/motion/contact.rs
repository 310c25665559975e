//! Root travel read from the feet.
//!
//! A generated motion carries its root's ground velocity as tokens of its
//! own, sampled beside the joint angles: nothing ties them to what the
//! legs do, so a body that stands can drift and a body that steps can
//! slide. [`FootLock`] replaces the root's ground displacement by the one
//! that keeps the supporting foot where it was: of the foot joints within
//! [`CONTACT_HEIGHT`] of the lowest height the feet have reached, on this
//! frame and the last, the one that would have moved least over the
//! ground had the root kept its last step bears the weight, and the root
//! moves by the opposite of that foot's move relative to it; with no foot
//! down (a jump, a run's flight) the displacement the motion carried is
//! kept. It is causal (each frame needs only the frames before it), so a
//! stream and a one-shot clip get the same path.
//!
//! The height too is the model's own token, so a generated body floats a
//! few centimetres or sinks into the floor whenever its legs bend other
//! than the height says. [`FootLock::ground_lift`] puts the lowest foot
//! joint on the floor (y = 0, where the vocabulary decodes the clip's
//! floor) when it is below it or within [`GROUND_SNAP`] above it, eases
//! out up to twice that, and leaves a higher body (a jump) as it is.
//! Tried and not kept: bringing a body down that stays up longer than a
//! jump (0.6 s): a plain-sampled clip that floats is mostly one holding its
//! legs up, and set on the floor it sits and stands by turns (Bandai
//! style, 90 clips, FID_k 33.6 → 274).

use super::clip::Motion;
use super::rotation::Vec3;
use super::skeleton::Skeleton;

/// How far above the lowest height its feet have reached a foot joint
/// still counts as standing on the floor (metres).
pub const CONTACT_HEIGHT: f64 = 0.08;

/// A lowest foot joint this close above the floor, or below it, is set
/// on it (metres); from here to twice this the lift eases out.
pub const GROUND_SNAP: f64 = 0.05;

/// Foot joints: those whose rest height lies within this of the lowest
/// rest joint's (metres): SMPL-13's ankles; SMPL-24's ankles and feet.
const FOOT_BAND: f64 = 0.15;

/// The causal foot-contact root path of one motion.
#[derive(Clone, Debug)]
pub struct FootLock {
    feet: Vec<usize>,
    floor: f64,
    /// The previous frame's foot positions (root at x = z = 0).
    prev: Option<Vec<Vec3>>,
    /// The root's last ground step.
    last: [f64; 2],
    ground: [f64; 2],
}

impl FootLock {
    pub fn new(skeleton: &Skeleton) -> FootLock {
        let rest = Motion::rest_positions(skeleton);
        let lowest = rest.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
        FootLock {
            feet: (0..rest.len())
                .filter(|&k| rest[k][1] <= lowest + FOOT_BAND)
                .collect(),
            floor: f64::INFINITY,
            prev: None,
            last: [0.0, 0.0],
            ground: [0.0, 0.0],
        }
    }

    /// The vertical move (metres, added to the root's height) that sets a
    /// pose's lowest foot joint on the floor y = 0: `−e` for a lowest foot
    /// at `e` < [`GROUND_SNAP`] (below the floor included), easing to 0 at
    /// 2 × GROUND_SNAP (the foot then at `2(e − GROUND_SNAP)`, continuous),
    /// nothing above (in the air). Stateless: each frame on its own.
    pub fn ground_lift(&self, pose: &[Vec3]) -> f64 {
        let e = self
            .feet
            .iter()
            .map(|&k| pose[k][1])
            .fold(f64::INFINITY, f64::min);
        if !e.is_finite() {
            0.0
        } else if e < GROUND_SNAP {
            -e
        } else if e < 2.0 * GROUND_SNAP {
            e - 2.0 * GROUND_SNAP
        } else {
            0.0
        }
    }

    /// One frame: its joint positions with the root's ground position
    /// held at x = z = 0 (its height as the motion has it), and the ground
    /// displacement (x, z) the motion carried since the previous frame.
    /// Returns the root's ground position (x, z); the first frame's is 0.
    pub fn step(&mut self, pose: &[Vec3], carried: [f64; 2]) -> [f64; 2] {
        let feet: Vec<Vec3> = self.feet.iter().map(|&k| pose[k]).collect();
        self.floor = feet.iter().map(|p| p[1]).fold(self.floor, f64::min);
        if let Some(prev) = &self.prev {
            let on_floor = |p: &Vec3| p[1] < self.floor + CONTACT_HEIGHT;
            // Each foot on the floor on both frames could bear the weight;
            // the one that does is the one that, had the root kept last
            // frame's step, would have moved least over the ground (a swing
            // foot touching down still moves forward; the planted one
            // does not).
            let world = |i: usize| {
                let r = [feet[i][0] - prev[i][0], feet[i][2] - prev[i][2]];
                (r[0] + self.last[0]).hypot(r[1] + self.last[1])
            };
            let support = (0..feet.len())
                .filter(|&i| on_floor(&feet[i]) && on_floor(&prev[i]))
                .min_by(|&a, &b| world(a).total_cmp(&world(b)));
            let d = match support {
                Some(i) => [prev[i][0] - feet[i][0], prev[i][2] - feet[i][2]],
                None => carried,
            };
            self.last = d;
            self.ground = [self.ground[0] + d[0], self.ground[1] + d[1]];
        }
        self.prev = Some(feet);
        self.ground
    }
}

/// The motion with its root's ground path rebuilt from foot contact
/// ([`FootLock`]) and its feet set on the floor y = 0
/// ([`FootLock::ground_lift`]); rotations and everything else unchanged.
pub fn lock_feet(m: &Motion) -> Motion {
    let j = m.joints();
    let mut flat = m.clone();
    for t in &mut flat.trans {
        (t[0], t[2]) = (0.0, 0.0);
    }
    let pose = flat.positions();
    let mut lock = FootLock::new(&m.skeleton);
    let mut out = m.clone();
    for f in 0..m.frames() {
        let carried = if f == 0 {
            [0.0, 0.0]
        } else {
            [
                m.trans[f][0] - m.trans[f - 1][0],
                m.trans[f][2] - m.trans[f - 1][2],
            ]
        };
        let here = &pose[f * j..(f + 1) * j];
        let g = lock.step(here, carried);
        out.trans[f][0] = m.trans[0][0] + g[0];
        out.trans[f][1] += lock.ground_lift(here);
        out.trans[f][2] = m.trans[0][2] + g[1];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SMPL-13 standing still (rest pose) for `n` frames, its root's
    /// ground position at `x(f)` and its ankles `y(f)` above the floor.
    fn standing(n: usize, x: impl Fn(usize) -> f64, y: impl Fn(usize) -> f64) -> Motion {
        let sk = Skeleton::smpl13();
        let j = sk.len();
        let ankle = Motion::rest_positions(&sk)
            .iter()
            .map(|p| p[1])
            .fold(f64::INFINITY, f64::min);
        let trans = (0..n).map(|f| [x(f), y(f) - ankle, 0.0]).collect();
        Motion::new(
            "t",
            20.0,
            sk,
            trans,
            vec![[0.0; 3]; n * j],
            Default::default(),
        )
        .unwrap()
    }

    #[test]
    fn the_feet_are_smpl13_ankles_and_smpl24_ankles_and_feet() {
        let f = |sk: &Skeleton| {
            let l = FootLock::new(sk);
            l.feet
                .iter()
                .map(|&k| sk.names[k].clone())
                .collect::<Vec<_>>()
        };
        let s13 = f(&Skeleton::smpl13());
        assert_eq!(s13, ["Left_Ankle", "Right_Ankle"]);
        assert_eq!(f(&Skeleton::smpl24()).len(), 4);
    }

    #[test]
    fn a_standing_body_that_drifts_stays_put() {
        // The carried path slides 5 cm a frame; the feet never move.
        let m = standing(30, |f| 0.05 * f as f64, |_| 0.0);
        let l = lock_feet(&m);
        for t in &l.trans {
            assert!((t[0] - m.trans[0][0]).abs() < 1e-12 && t[2].abs() < 1e-12);
        }
        assert_eq!(
            l.trans.iter().map(|t| t[1]).collect::<Vec<_>>(),
            m.trans.iter().map(|t| t[1]).collect::<Vec<_>>()
        );
        assert_eq!(l.rotations, m.rotations);
    }

    #[test]
    fn the_feet_are_set_on_the_floor_unless_in_the_air() {
        // Ankles sunk 4 cm, on the floor, floating 3, 7 and 12 cm, and
        // 30 cm up: the first three go to the floor, 7 cm eases to
        // 2 × (7 − 5) = 4 cm, the rest stay.
        let ys = [-0.04, 0.0, 0.03, 0.07, 0.12, 0.3];
        let m = standing(ys.len(), |_| 0.0, |f| ys[f]);
        let l = lock_feet(&m);
        let want = [0.0, 0.0, 0.0, 0.04, 0.12, 0.3];
        for f in 0..ys.len() {
            let d = l.trans[f][1] - m.trans[f][1];
            assert!(
                (ys[f] + d - want[f]).abs() < 1e-9,
                "frame {f}: {}",
                ys[f] + d
            );
        }
        // The lift is continuous where it eases out.
        let sk = Skeleton::smpl13();
        let lock = FootLock::new(&sk);
        let at = |e: f64| {
            let mm = standing(1, |_| 0.0, |_| e);
            e + lock.ground_lift(&mm.positions())
        };
        for e in [GROUND_SNAP, 2.0 * GROUND_SNAP] {
            assert!((at(e - 1e-9) - at(e + 1e-9)).abs() < 1e-6, "at {e}");
        }
    }

    #[test]
    fn in_the_air_the_carried_path_is_kept() {
        // Frames 0–4 on the floor, then rising 20 cm a frame while moving
        // 3 cm a frame: every airborne step keeps the carried displacement.
        let m = standing(
            12,
            |f| 0.03 * f as f64,
            |f| 0.2 * f.saturating_sub(4) as f64,
        );
        let l = lock_feet(&m);
        for f in 0..=4 {
            assert!((l.trans[f][0] - m.trans[0][0]).abs() < 1e-12, "frame {f}");
        }
        for f in 6..12 {
            let (d, want) = (l.trans[f][0] - l.trans[f - 1][0], 0.03);
            assert!((d - want).abs() < 1e-12, "frame {f}: {d}");
        }
    }

    #[test]
    fn a_planted_foot_under_a_turning_body_carries_the_root() {
        // The body turns about its vertical axis; the left ankle is the
        // lower one (the right leg lifted) and stays planted: the root
        // moves so that the ankle's world position does not change.
        let sk = Skeleton::smpl13();
        let j = sk.len();
        let rhip = sk.index_of("Right_Hip").unwrap();
        let lank = sk.index_of("Left_Ankle").unwrap();
        let n = 10;
        let mut rot = vec![[0.0; 3]; n * j];
        for f in 0..n {
            rot[f * j] = [0.0, 0.1 * f as f64, 0.0];
            rot[f * j + rhip] = [-0.6, 0.0, 0.0];
        }
        let m = Motion::new("turn", 20.0, sk, vec![[0.0; 3]; n], rot, Default::default()).unwrap();
        let l = lock_feet(&m);
        let p = l.positions();
        for f in 1..n {
            for k in [0, 2] {
                let d = p[f * j + lank][k] - p[lank][k];
                assert!(
                    d.abs() < 1e-9,
                    "frame {f} axis {k}: the planted ankle moved {d}"
                );
            }
        }
    }
}
