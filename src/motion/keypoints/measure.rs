//! How far solved rotations are from the truth, per SMPL-13 joint.

use super::*;
use crate::motion::clip::Motion;
use crate::motion::rotation::*;
use crate::motion::skeleton::Skeleton;
use serde::Serialize;

/// How [`joint_errors`] measures a joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Measure {
    /// The bone's direction in its parent's frame (the joint's own twist
    /// excluded). For knees and elbows this includes the parent's twist
    /// about its bone, which keypoints do not show: the error then says how
    /// far the solver's choice of thigh / upper-arm twist is from the one
    /// the mocap fit happened to make.
    ParentFrame,
    /// What keypoints can show: for knees and elbows the bone's direction
    /// in the parent's frame with the parent's twist removed too (the
    /// least rotation carrying the parent bone from rest); other joints as
    /// [`Measure::ParentFrame`].
    Observable,
}

/// Per-joint IK error, degrees, of `solved` against `truth` (both SMPL-24,
/// same frames), on the SMPL-13 joints: for each joint that bends a bone the
/// angle between the bone's directions as `measure` says; for the pelvis the
/// whole rotation. Returns `(joint name, errors over frames)`; joints whose
/// bone the layout does not observe are left out.
pub fn joint_errors(
    layout: Layout,
    solved: &Motion,
    truth: &Motion,
    measure: Measure,
) -> Vec<(String, Vec<f64>)> {
    let sk = Skeleton::smpl24();
    let frames = solved.frames().min(truth.frames());
    let s13 = |m: &Motion| m.to_smpl13().ok();
    let (Some(a), Some(b)) = (s13(solved), s13(truth)) else {
        return Vec::new();
    };
    let sem = layout.semantic();
    let rest = Motion::rest_positions(&sk);
    let dir = |from: usize, to: usize| normalize(sub(rest[to], rest[from]));
    // (13-joint index, its bone's rest direction, the parent's (13-joint
    // index, bone direction) for knees and elbows)
    type Spec = (usize, Option<Vec3>, Option<(usize, Vec3)>);
    let mut joints: Vec<Spec> = vec![(0, None, None)];
    for side in 0..2 {
        let (leg, arm) = (LEG[side], ARM[side]);
        let thigh = dir(leg[0], leg[1]).expect("rest bone");
        let upper = dir(arm[0], arm[1]).expect("rest bone");
        joints.push((1 + side, Some(thigh), None));
        joints.push((3 + side, dir(leg[1], leg[2]), Some((1 + side, thigh))));
        if sem.toe.is_some() {
            joints.push((5 + side, dir(leg[2], leg[3]), None));
        }
        joints.push((7 + side, Some(upper), None));
        joints.push((9 + side, dir(arm[1], arm[2]), Some((7 + side, upper))));
        if sem.hand.is_some() {
            joints.push((11 + side, dir(arm[2], arm[3]), None));
        }
    }
    joints.sort_by_key(|j| j.0);
    let names = Skeleton::smpl13().names;
    let seen = |m: &Motion, f: usize, j: usize, d: Vec3, parent: Option<(usize, Vec3)>| {
        let local = quat_rotate(axis_angle_to_quat(m.rot(f, j)), d);
        match (measure, parent) {
            (Measure::Observable, Some((p, pd))) => {
                let lp = axis_angle_to_quat(m.rot(f, p));
                let swing = quat_between(pd, quat_rotate(lp, pd));
                quat_rotate(quat_conj(swing), quat_rotate(lp, local))
            }
            _ => local,
        }
    };
    joints
        .into_iter()
        .map(|(j, d, parent)| {
            let errs = (0..frames)
                .map(|f| match d {
                    None => geodesic_quat(
                        axis_angle_to_quat(a.rot(f, j)),
                        axis_angle_to_quat(b.rot(f, j)),
                    )
                    .to_degrees(),
                    Some(d) => dot(seen(&a, f, j, d, parent), seen(&b, f, j, d, parent))
                        .clamp(-1.0, 1.0)
                        .acos()
                        .to_degrees(),
                })
                .collect();
            (names[j].clone(), errs)
        })
        .collect()
}
