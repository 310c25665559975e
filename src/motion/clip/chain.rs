//! Takes played one after another as one motion (`choreo-train
//! --chain-takes`).

use super::*;

impl Motion {
    /// Seconds of SLERP that join two chained takes (`choreo-train
    /// --chain-takes`, and the real takes of `eval generate`'s
    /// `real_chained`).
    pub const CHAIN_BRIDGE_S: f64 = 0.1;

    /// Takes played one after another as one motion, each entering where
    /// it best goes on from the last: the next take starts at the frame
    /// after its pose nearest the chain's last pose (every joint but the
    /// root; searched over its first half, the root's ground speed counted
    /// too, in m/s against radians), is turned about the vertical to face
    /// as the chain faces, and is placed where the root's last ground
    /// velocity carries it over `bridge + 1` frames (its own height kept).
    /// The `bridge` frames between SLERP every joint and lerp the root, so
    /// a run goes on running and a still take stays still. A take of one
    /// frame has nothing to enter and is left out. The takes must share the
    /// first one's joints and frame rate; the chain has its skeleton, name
    /// and labels.
    pub fn chain(takes: &[Motion], bridge: usize) -> Result<Motion, MotionError> {
        let first = takes
            .first()
            .ok_or_else(|| MotionError::invalid("chain", "takes", "no take to chain"))?;
        let j = first.joints();
        let o0 = first.skeleton.offsets[0];
        let facing = |m: &Motion, f: usize| {
            m.facing(f).ok_or_else(|| {
                MotionError::invalid(
                    &m.name,
                    "skeleton",
                    "cannot tell which way the body faces (no left/right hips found)",
                )
            })
        };
        let ground = |p: Vec3| [p[0], 0.0, p[2]];
        let (mut trans, mut rots) = (first.trans.clone(), first.rotations.clone());
        for t in &takes[1..] {
            if t.skeleton.parents != first.skeleton.parents || (t.fps - first.fps).abs() > 1e-9 {
                return Err(MotionError::invalid(
                    &t.name,
                    "skeleton",
                    format!(
                        "its joints or frame rate differ from {}'s; only alike takes chain",
                        first.name
                    ),
                ));
            }
            if t.frames() < 2 {
                continue;
            }
            let last = trans.len() - 1;
            let step = if last > 0 {
                ground(sub(trans[last], trans[last - 1]))
            } else {
                [0.0; 3]
            };
            let speed = |f: usize| norm(ground(sub(t.trans[f], t.trans[f - 1])));
            let cost = |f: usize| {
                let pose: f64 = (1..j)
                    .map(|k| geodesic_axis_angle(rots[last * j + k], t.rot(f - 1, k)))
                    .sum();
                pose + (speed(f) - norm(step)).abs() * t.fps
            };
            let entry = (1..=(t.frames() / 2).max(1))
                .min_by(|&a, &b| cost(a).total_cmp(&cost(b)))
                .unwrap_or(1);
            let so_far = first.with_data(trans[last..].to_vec(), rots[last * j..].to_vec());
            let (fa, fb) = (facing(&so_far, 0)?, facing(t, entry - 1)?);
            let yaw = axis_angle_to_quat([0.0, cross(fb, fa)[1].atan2(dot(fb, fa)), 0.0]);
            let from = ground(add(t.skeleton.offsets[0], t.trans[entry]));
            let at = add(
                ground(add(o0, trans[last])),
                scale(step, (bridge + 1) as f64),
            );
            let next = t.cut(entry, t.frames())?.turned(yaw, from, at);
            // On the first take's skeleton: the same world path.
            let rebase = sub(t.skeleton.offsets[0], o0);
            let next_trans: Vec<Vec3> = next.trans.iter().map(|&tr| add(tr, rebase)).collect();
            for i in 1..=bridge {
                let a = i as f64 / (bridge + 1) as f64;
                trans.push(lerp3(trans[last], next_trans[0], a));
                for k in 0..j {
                    let (qa, qb) = (
                        axis_angle_to_quat(rots[last * j + k]),
                        axis_angle_to_quat(next.rotations[k]),
                    );
                    rots.push(quat_to_axis_angle(slerp(qa, qb, a)));
                }
            }
            trans.extend(next_trans);
            rots.extend(next.rotations);
        }
        let out = first.with_data(trans, rots);
        out.validate()?;
        Ok(out)
    }
}
