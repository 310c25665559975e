//! Feet that stay where they touch the floor: leg inverse kinematics.
//!
//! [`super::contact`] moves the *root* so that the supporting foot does
//! not slide; that needs a root that travels, and cannot stop two feet
//! sliding apart, or a foot sliding under a body that dances in place (a
//! corpus without root trajectory, a rig that streams rotations only).
//! [`FootPin`] changes the *legs* instead. A foot joint that comes within
//! [`PIN_HEIGHT`] of its floor (the lowest it has reached, at most
//! [`FLOOR_SPREAD`] above the lowest either foot has reached) moving
//! slower than [`PIN_SPEED`] over the
//! ground is pinned where it touched; it stays down, however it slides,
//! until it rises [`PIN_LIFT`] above the pin or moves faster than twice
//! [`PIN_SPEED`]. While it is down, the hip and
//! knee rotations are solved (two-bone IK, the knee bending in the plane
//! it already bends in) so the ankle reaches the pin, and the ankle's own
//! rotation is set so the foot keeps the orientation the motion gave it.
//! A foot drifting further than [`PIN_REACH`] from its pin drags the pin
//! along; a foot that lifts (or speeds up) is released over
//! [`RELEASE_FRAMES`] or more, the correction fading out at most
//! [`RELEASE_STEP`] a frame, so nothing pops. The
//! root, the upper body and the frames without contact are unchanged.
//!
//! Causal: each frame needs only the frames before it, so a stream and a
//! one-shot clip get the same legs.

use super::clip::Motion;
use super::rotation::{
    add, axis_angle_to_quat, cross, dot, norm, normalize, quat_conj, quat_mul, quat_rotate,
    quat_to_axis_angle, scale, sub, Quat, Vec3, IDENTITY_QUAT,
};
use super::skeleton::Skeleton;

/// A foot joint this close above its floor (metres) may be pinned …
pub const PIN_HEIGHT: f64 = 0.05;
/// A foot's floor is the lowest height it has reached itself, but no
/// higher than this above the lowest either foot has reached (metres).
/// Generated legs are not symmetric to the millimetre: the two ankles'
/// lowest heights differ by over 3.7 cm in a quarter of the frame
/// model's AIST++ clips (by under 1 cm in three quarters of real takes),
/// and measured from the shared floor the higher foot was never pinned
/// though it stood (docs/RESULTS.md, "Session 52"). The cap
/// keeps a foot held up all along (a leg raised from the first frame)
/// from being pinned in the air.
pub const FLOOR_SPREAD: f64 = 0.05;
/// … when it moves slower than this over the ground (m/s); a pinned foot
/// is let go when it moves faster than twice this …
pub const PIN_SPEED: f64 = 0.8;
/// … or rises this far above its pin (metres).
pub const PIN_LIFT: f64 = 0.025;
/// The farthest a pinned foot's own (unpinned) position may drift from
/// its pin before the pin follows it (metres).
pub const PIN_REACH: f64 = 0.3;
/// Frames over which a released foot's correction fades to nothing (at
/// least; more for a large one, [`RELEASE_STEP`]).
pub const RELEASE_FRAMES: usize = 4;
/// The most a fading correction moves the ankle in one frame (metres).
pub const RELEASE_STEP: f64 = 0.02;

/// The joints whose rotations pinning may change (SMPL names); every
/// other joint, and the root's translation, stay as they were.
pub const LEG_JOINTS: [&str; 6] = [
    "Left_Hip",
    "Right_Hip",
    "Left_Knee",
    "Right_Knee",
    "Left_Ankle",
    "Right_Ankle",
];

/// One leg: hip, knee and ankle joint indices, and its contact state.
#[derive(Clone, Debug)]
struct Leg {
    hip: usize,
    knee: usize,
    ankle: usize,
    pin: Option<Vec3>,
    /// The lowest height this ankle has reached (unpinned).
    floor: f64,
    /// The ankle's unpinned position on the previous frame.
    prev: Option<Vec3>,
    /// After a release: the correction (pinned − free) at release, the
    /// frames since, and the frames it fades over.
    fading: Option<(Vec3, usize, usize)>,
}

/// The causal leg IK of one motion ([`pin_feet`] for a whole clip).
#[derive(Clone, Debug)]
pub struct FootPin {
    legs: Vec<Leg>,
    fps: f64,
}

impl FootPin {
    /// The legs of a skeleton: each `Left_Ankle` / `Right_Ankle` with its
    /// parent (knee) and grandparent (hip). `None` for a skeleton without
    /// both.
    pub fn new(skeleton: &Skeleton, fps: f64) -> Option<FootPin> {
        let mut legs = Vec::new();
        for name in ["Left_Ankle", "Right_Ankle"] {
            let ankle = skeleton.index_of(name)?;
            let knee = skeleton.parents[ankle]?;
            let hip = skeleton.parents[knee]?;
            legs.push(Leg {
                hip,
                knee,
                ankle,
                pin: None,
                floor: f64::INFINITY,
                prev: None,
                fading: None,
            });
        }
        Some(FootPin { legs, fps })
    }

    /// One frame: its local rotations (changed in place: hips, knees and
    /// ankles of pinned or fading legs) under the root translation `trans`.
    pub fn step(&mut self, skeleton: &Skeleton, rotations: &mut [Vec3], trans: Vec3) {
        let (glob, pos) = frame_fk(skeleton, rotations, trans);
        for leg in &mut self.legs {
            leg.floor = leg.floor.min(pos[leg.ankle][1]);
        }
        // The lowest either foot has reached.
        let shared = self
            .legs
            .iter()
            .map(|l| l.floor)
            .fold(f64::INFINITY, f64::min);
        for li in 0..self.legs.len() {
            let leg = &mut self.legs[li];
            let free = pos[leg.ankle];
            let speed = leg
                .prev
                .map_or(0.0, |p| (free[0] - p[0]).hypot(free[2] - p[2]) * self.fps);
            leg.prev = Some(free);
            // Down: a foot comes down low and slow; it stays down while it
            // slides along the floor (what skating is), and is up again
            // once it rises off its pin (a heel lifting: a step) or moves
            // fast (footwork, a kick).
            let down = match leg.pin {
                None => {
                    let floor = leg.floor.min(shared + FLOOR_SPREAD);
                    free[1] < floor + PIN_HEIGHT && speed < PIN_SPEED
                }
                Some(pin) => free[1] < pin[1] + PIN_LIFT && speed < 2.0 * PIN_SPEED,
            };

            let target = if down {
                // A foot that comes down again while its last correction
                // fades is pinned where the fade has it, not where the
                // model put it (which would jump back).
                let start = match leg.fading.take() {
                    Some((off, k, frames)) => add(
                        free,
                        scale(off, 1.0 - (k + 1) as f64 / (frames as f64 + 1.0)),
                    ),
                    None => free,
                };
                let mut pin = leg.pin.unwrap_or(start);
                let drift = sub(pin, free);
                let d = norm(drift);
                if d > PIN_REACH {
                    pin = add(free, scale(drift, PIN_REACH / d));
                }
                leg.pin = Some(pin);
                pin
            } else {
                if let Some(pin) = leg.pin.take() {
                    let off = sub(pin, free);
                    let frames = RELEASE_FRAMES.max((norm(off) / RELEASE_STEP).ceil() as usize);
                    leg.fading = Some((off, 0, frames));
                }
                match &mut leg.fading {
                    Some((off, k, frames)) => {
                        *k += 1;
                        let w = 1.0 - *k as f64 / (*frames as f64 + 1.0);
                        let t = add(free, scale(*off, w));
                        if *k >= *frames {
                            leg.fading = None;
                        }
                        t
                    }
                    None => free,
                }
            };
            if norm(sub(target, free)) > 1e-9 {
                let leg = &self.legs[li];
                solve_leg(skeleton, rotations, &glob, &pos, leg, target);
            }
        }
    }
}

/// One frame's global rotations and joint positions.
fn frame_fk(skeleton: &Skeleton, rotations: &[Vec3], trans: Vec3) -> (Vec<Quat>, Vec<Vec3>) {
    let mut glob = vec![IDENTITY_QUAT; skeleton.len()];
    let mut pos = Vec::with_capacity(skeleton.len());
    super::clip::frame_fk(skeleton, rotations, trans, &mut glob, &mut pos);
    (glob, pos)
}

fn axis_quat(axis: Vec3, angle: f64) -> Quat {
    axis_angle_to_quat(scale(axis, angle))
}

fn angle_between(a: Vec3, b: Vec3) -> f64 {
    match (normalize(a), normalize(b)) {
        (Some(a), Some(b)) => dot(a, b).clamp(-1.0, 1.0).acos(),
        _ => 0.0,
    }
}

/// Two-bone IK: hip and knee rotated so the ankle reaches `target` (or
/// as near as the leg's length allows), the knee bending in its current
/// plane; the ankle's global orientation kept.
fn solve_leg(
    skeleton: &Skeleton,
    rotations: &mut [Vec3],
    glob: &[Quat],
    pos: &[Vec3],
    leg: &Leg,
    target: Vec3,
) {
    let (a, b, c) = (pos[leg.hip], pos[leg.knee], pos[leg.ankle]);
    let (l1, l2) = (norm(sub(b, a)), norm(sub(c, b)));
    if l1 < 1e-9 || l2 < 1e-9 {
        return;
    }
    let eps = 1e-4;
    let d = norm(sub(target, a)).clamp((l1 - l2).abs() + eps, l1 + l2 - eps);
    let acos = |x: f64| x.clamp(-1.0, 1.0).acos();
    // Present and wanted angles: at the hip between the hip→ankle line and
    // the thigh, at the knee between thigh and shin.
    let hip_now = angle_between(sub(c, a), sub(b, a));
    let knee_now = angle_between(sub(a, b), sub(c, b));
    let hip_want = acos((l2 * l2 - l1 * l1 - d * d) / (-2.0 * l1 * d));
    let knee_want = acos((d * d - l1 * l1 - l2 * l2) / (-2.0 * l1 * l2));
    // The bend plane's normal; a straight leg bends about the knee's own
    // first axis (SMPL knees flex about x).
    let bend = normalize(cross(sub(c, a), sub(b, a)))
        .unwrap_or_else(|| quat_rotate(glob[leg.knee], [1.0, 0.0, 0.0]));
    let (gh, gk) = (glob[leg.hip], glob[leg.knee]);
    let rot_global = |g: Quat, axis: Vec3, angle: f64| -> Quat {
        // A turn about a global axis, composed on a joint's global rotation.
        quat_mul(axis_quat(axis, angle), g)
    };
    let mut gh2 = rot_global(gh, bend, hip_want - hip_now);
    let mut gk2 = quat_mul(gh2, quat_mul(quat_conj(gh), gk));
    gk2 = rot_global(gk2, bend, knee_want - knee_now);
    // The ankle where the bent leg now puts it; turn the hip so it points
    // at the target.
    let hip_to_knee = quat_rotate(gh2, skeleton.offsets[leg.knee]);
    let knee_to_ankle = quat_rotate(gk2, skeleton.offsets[leg.ankle]);
    let c2 = add(add(a, hip_to_knee), knee_to_ankle);
    let (u, v) = (sub(c2, a), sub(target, a));
    if let Some(axis) = normalize(cross(u, v)) {
        let turn = axis_quat(axis, angle_between(u, v));
        gh2 = quat_mul(turn, gh2);
        gk2 = quat_mul(turn, gk2);
    }
    let parent = skeleton.parents[leg.hip].map_or(IDENTITY_QUAT, |p| glob[p]);
    rotations[leg.hip] = quat_to_axis_angle(quat_mul(quat_conj(parent), gh2));
    rotations[leg.knee] = quat_to_axis_angle(quat_mul(quat_conj(gh2), gk2));
    rotations[leg.ankle] = quat_to_axis_angle(quat_mul(quat_conj(gk2), glob[leg.ankle]));
}

/// A whole motion with its feet pinned ([`FootPin`]); unchanged when the
/// skeleton has no legs it knows.
pub fn pin_feet(m: &Motion) -> Motion {
    let Some(mut pin) = FootPin::new(&m.skeleton, m.fps) else {
        return m.clone();
    };
    let j = m.joints();
    let mut out = m.clone();
    for f in 0..m.frames() {
        let trans = m.trans[f];
        pin.step(&m.skeleton, &mut out.rotations[f * j..(f + 1) * j], trans);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ankle_paths(m: &Motion) -> Vec<[Vec3; 2]> {
        let p = m.positions();
        let j = m.joints();
        let (l, r) = (
            m.skeleton.index_of("Left_Ankle").unwrap(),
            m.skeleton.index_of("Right_Ankle").unwrap(),
        );
        (0..m.frames())
            .map(|f| [p[f * j + l], p[f * j + r]])
            .collect()
    }

    /// 40 frames at 20 fps standing in place, one leg's hip flexing by
    /// up to 0.08 rad and back (a half sine) and its knee at
    /// `knee(flexion)`; returns it with the leg's hip and knee indices.
    fn hip_swing(side: &str, knee: impl Fn(f64) -> f64) -> (Motion, usize, usize) {
        let sk = Skeleton::smpl13();
        let j = sk.len();
        let h = sk.index_of(&format!("{side}_Hip")).unwrap();
        let k = sk.index_of(&format!("{side}_Knee")).unwrap();
        let n = 40;
        let mut rot = vec![[0.0; 3]; n * j];
        for f in 0..n {
            let a = 0.08 * (f as f64 / n as f64 * std::f64::consts::PI).sin();
            rot[f * j + h] = [-a, 0.0, 0.0];
            rot[f * j + k] = [knee(a), 0.0, 0.0];
        }
        let m = Motion::new("t", 20.0, sk, vec![[0.0; 3]; n], rot, Default::default()).unwrap();
        (m, h, k)
    }

    /// A body standing in place whose left hip swings slowly forward and
    /// back, so the left foot slides along the floor: pinned, the ankle
    /// stays within a few millimetres of where it touched, the right leg
    /// and the root are untouched, and bone lengths are kept.
    #[test]
    fn a_sliding_foot_stays_where_it_touched() {
        // A matching knee bend: the foot moves ~7 cm along the ground and
        // ~3 mm up over the clip.
        let (m, hip, knee) = hip_swing("Left", |a| 0.2 * a);
        let (sk, j, n) = (m.skeleton.clone(), m.joints(), m.frames());
        let before = ankle_paths(&m);
        let slide = before
            .iter()
            .map(|p| norm(sub(p[0], before[0][0])))
            .fold(0.0, f64::max);
        assert!(slide > 0.03, "the test foot slides ({slide} m)");
        let out = pin_feet(&m);
        let after = ankle_paths(&out);
        for (f, p) in after.iter().enumerate() {
            let d = norm(sub(p[0], after[0][0]));
            assert!(d < 0.005, "frame {f}: left ankle moved {d} m");
            assert!(norm(sub(p[1], before[f][1])) < 1e-9, "right leg untouched");
        }
        let pos = out.positions();
        let rest = Motion::rest_positions(&sk);
        let len = |p: &[Vec3], a: usize, b: usize| norm(sub(p[a], p[b]));
        for f in 0..n {
            let fp = &pos[f * j..(f + 1) * j];
            assert!((len(fp, hip, knee) - len(&rest, hip, knee)).abs() < 1e-9);
        }
        assert_eq!(out.trans, m.trans);
    }

    /// One leg bent at the knee the whole clip, its hip swinging slowly:
    /// its ankle's lowest lies some centimetres above the other's. Within
    /// [`FLOOR_SPREAD`] it stands on its own floor and is pinned; held far
    /// higher (a leg raised from the first frame) it is left in the air.
    #[test]
    fn a_foot_standing_higher_than_the_other_is_pinned_on_its_own_floor() {
        let clip = |bend: f64| hip_swing("Right", move |_| bend).0;
        let n = clip(0.0).frames();
        let rise = |m: &Motion| {
            let p = ankle_paths(m);
            let low = |k: usize| p.iter().map(|a| a[k][1]).fold(f64::INFINITY, f64::min);
            low(1) - low(0)
        };
        let standing = clip(0.55);
        let r = rise(&standing);
        assert!(
            r > PIN_HEIGHT && r < PIN_HEIGHT + FLOOR_SPREAD,
            "the bent leg's ankle stands {r} m above the other's"
        );
        let before = ankle_paths(&standing);
        let slide = before
            .iter()
            .map(|p| (p[1][0] - before[0][1][0]).hypot(p[1][2] - before[0][1][2]))
            .fold(0.0, f64::max);
        assert!(slide > 0.03, "the bent leg's foot slides ({slide} m)");
        let after = ankle_paths(&pin_feet(&standing));
        for (f, p) in after.iter().enumerate() {
            let d = norm(sub(p[1], after[0][1]));
            assert!(d < 0.005, "frame {f}: the bent leg's ankle moved {d} m");
        }
        let raised = clip(1.1);
        let r = rise(&raised);
        assert!(r > 2.0 * PIN_HEIGHT + FLOOR_SPREAD, "raised {r} m");
        let (before, after) = (ankle_paths(&raised), ankle_paths(&pin_feet(&raised)));
        for f in 0..n {
            assert!(
                norm(sub(after[f][1], before[f][1])) < 1e-9,
                "frame {f}: raised foot left alone"
            );
        }
    }

    /// A foot lifted off the floor, or moving fast, is left as it is; a
    /// released foot returns to its own path within the release frames.
    #[test]
    fn a_stepping_foot_is_released_smoothly() {
        let sk = Skeleton::smpl13();
        let j = sk.len();
        let hip = sk.index_of("Left_Hip").unwrap();
        let knee = sk.index_of("Left_Knee").unwrap();
        let n = 30;
        let mut rot = vec![[0.0; 3]; n * j];
        for f in 0..n {
            // Frames 0–9 slide slowly; from 10 the thigh lifts (knee up).
            let a = if f < 10 {
                0.004 * f as f64
            } else {
                0.04 + 0.12 * (f - 9) as f64
            };
            let k = if f < 10 { 0.0 } else { 0.2 * (f - 9) as f64 };
            rot[f * j + hip] = [-a.min(1.2), 0.0, 0.0];
            rot[f * j + knee] = [k.min(1.5), 0.0, 0.0];
        }
        let m = Motion::new("t", 20.0, sk, vec![[0.0; 3]; n], rot, Default::default()).unwrap();
        let (before, after) = (ankle_paths(&m), ankle_paths(&pin_feet(&m)));
        // Pinned at frame 0 (down from the start); let go once it rises
        // PIN_LIFT above the pin or moves faster than twice PIN_SPEED.
        let pin = before[0][0];
        let lifted = (1..n)
            .find(|&f| {
                let (p, q) = (before[f][0], before[f - 1][0]);
                p[1] > pin[1] + PIN_LIFT
                    || (p[0] - q[0]).hypot(p[2] - q[2]) * 20.0 > 2.0 * PIN_SPEED
            })
            .expect("the foot lifts");
        let off = norm(sub(after[lifted - 1][0], before[lifted][0]));
        let fade = RELEASE_FRAMES.max((off / RELEASE_STEP).ceil() as usize);
        assert!(
            lifted + fade < n - 2,
            "lifted at {lifted}, fades over {fade}"
        );
        assert!(
            norm(sub(after[lifted - 1][0], before[lifted - 1][0])) > 1e-4,
            "pinned before"
        );
        for f in lifted + fade..n {
            assert!(
                norm(sub(after[f][0], before[f][0])) < 1e-9,
                "frame {f} released"
            );
        }
        // No frame-to-frame jump of the corrected ankle beyond the free one's.
        for f in 1..n {
            let step_after = norm(sub(after[f][0], after[f - 1][0]));
            let step_before = norm(sub(before[f][0], before[f - 1][0]));
            assert!(
                step_after <= 1.3 * step_before + 0.005,
                "frame {f}: {step_after} vs {step_before}"
            );
        }
    }
}
