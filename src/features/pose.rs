//! The pose embedding: what a window looks like from outside, so that
//! motion capture and motion estimated from video can find each other.
//!
//! Rotation channels carry choices the eye cannot see (twist about a bone,
//! how a bend is shared along the spine, collars and hands), and a video
//! estimator and a mocap fit make them differently. Joint positions do not.
//! Per frame of the `[72][128]` window: forward kinematics on the SMPL
//! neutral body (so proportions and units are the same for every source),
//! the positions of 13 joints relative to the pelvis (hips, knees, ankles,
//! shoulders, elbows, wrists, head), turned about the vertical so that the
//! pelvis faces +z at the window's middle frame (the camera's heading, or
//! the capture room's, does not matter). Each of the 39 coordinates'
//! 128-sample series keeps its first 16 orthonormal DCT-II coefficients:
//! 624 values.

use super::{CHANNELS, COEFFS, WINDOW};
use crate::motion::rotation::*;
use crate::motion::Skeleton;

/// SMPL-24 joints whose positions the embedding keeps.
pub const POSE_JOINTS: [usize; 13] = [1, 2, 4, 5, 7, 8, 16, 17, 18, 19, 20, 21, 15];
/// Values per window.
pub const POSE_DIM: usize = POSE_JOINTS.len() * 3 * COEFFS;

/// Positions of [`POSE_JOINTS`] relative to the pelvis for one frame's 24
/// local rotations, and the pelvis's global rotation.
fn frame_positions(
    local: &[Vec3; 24],
    offsets: &[Vec3],
    parents: &[Option<usize>],
) -> ([Vec3; 24], Quat) {
    let mut glob = [IDENTITY_QUAT; 24];
    let mut pos = [[0.0; 3]; 24];
    for j in 0..24 {
        let q = axis_angle_to_quat(local[j]);
        match parents[j] {
            None => glob[j] = q,
            Some(p) => {
                glob[j] = quat_mul(glob[p], q);
                pos[j] = add(pos[p], quat_rotate(glob[p], offsets[j]));
            }
        }
    }
    (pos, glob[0])
}

/// The pose embedding of one channel-major `[72][128]` window.
pub fn pose_embedding(win: &[f32], basis: &[f32]) -> Vec<f32> {
    debug_assert_eq!(win.len(), CHANNELS * WINDOW);
    let sk = Skeleton::smpl24();
    let mut series = vec![0f32; POSE_JOINTS.len() * 3 * WINDOW];
    let mut poses = Vec::with_capacity(WINDOW);
    for t in 0..WINDOW {
        let mut local = [[0.0; 3]; 24];
        for (j, l) in local.iter_mut().enumerate() {
            for c in 0..3 {
                l[c] = win[(j * 3 + c) * WINDOW + t] as f64;
            }
        }
        poses.push(frame_positions(&local, &sk.offsets, &sk.parents));
    }
    // Heading of the pelvis at the middle frame: its forward axis on the floor.
    let fwd = quat_rotate(poses[WINDOW / 2].1, [0.0, 0.0, 1.0]);
    let yaw = fwd[0].atan2(fwd[2]);
    let unturn = axis_angle_to_quat([0.0, -yaw, 0.0]);
    for (t, (pos, _)) in poses.iter().enumerate() {
        for (i, &j) in POSE_JOINTS.iter().enumerate() {
            let p = quat_rotate(unturn, pos[j]);
            for c in 0..3 {
                series[(i * 3 + c) * WINDOW + t] = p[c] as f32;
            }
        }
    }
    let channels = POSE_JOINTS.len() * 3;
    let mut out = vec![0f32; channels * COEFFS];
    for ch in 0..channels {
        let x = &series[ch * WINDOW..(ch + 1) * WINDOW];
        for k in 0..COEFFS {
            let b = &basis[k * WINDOW..(k + 1) * WINDOW];
            out[ch * COEFFS + k] = x.iter().zip(b).map(|(a, b)| a * b).sum();
        }
    }
    out
}
