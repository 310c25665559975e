//! Tests of `motion/clip.rs`.

use super::*;

#[test]
fn despike_repairs_a_one_frame_flip_and_leaves_fast_turns() {
    let mut m = sine_clip(60, 60.0);
    let j = m.joints();
    // Frame 20: the root flips 85° about y for one frame.
    let r0 = m.rotations[20 * j];
    m.rotations[20 * j] = quat_to_axis_angle(quat_mul(
        axis_angle_to_quat([0.0, 85f64.to_radians(), 0.0]),
        axis_angle_to_quat(r0),
    ));
    // Frames 40..: spine1 turns 1 rad a frame for good (no return).
    for f in 40..60 {
        m.rotations[f * j + 3] = [0.0, (f - 39) as f64, 0.0];
    }
    let (d, fixed) = m.despike(3, 30f64.to_radians());
    assert_eq!(fixed, 1);
    assert!(geodesic_axis_angle(d.rotations[20 * j], r0) < 1e-9);
    assert_eq!(
        d.rotations[40 * j + 3..].to_vec(),
        m.rotations[40 * j + 3..].to_vec()
    );
}

/// A hand-checkable SMPL clip: the left elbow swings about z as a sine,
/// the root walks along +x.
pub fn sine_clip(frames: usize, fps: f64) -> Motion {
    let sk = Skeleton::smpl24();
    let mut rots = vec![[0.0; 3]; frames * 24];
    let mut trans = Vec::new();
    for f in 0..frames {
        let t = f as f64 / fps;
        rots[f * 24 + 18] = [0.0, 0.0, 0.8 * (2.0 * std::f64::consts::PI * t).sin()];
        rots[f * 24 + 1] = [0.3 * t.sin(), 0.1, 0.0];
        trans.push([0.5 * t, 0.9, 0.0]);
    }
    Motion::new("sine", fps, sk, trans, rots, Labels::new()).unwrap()
}

#[test]
fn fk_rest_pose_is_sum_of_offsets() {
    let sk = Skeleton::smpl24();
    let m = Motion::new(
        "rest",
        30.0,
        sk.clone(),
        vec![[0.0; 3]],
        vec![[0.0; 3]; 24],
        Labels::new(),
    )
    .unwrap();
    let pos = m.positions();
    let rest = Motion::rest_positions(&sk);
    for k in 0..24 {
        for a in 0..3 {
            assert!((pos[k][a] - rest[k][a]).abs() < 1e-12);
        }
    }
}

#[test]
fn fk_elbow_bend_moves_wrist_by_hand() {
    // Rotating the left elbow by 90° about y swings the forearm (offset
    // along +x) to point along -z.
    let sk = Skeleton::smpl24();
    let mut rots = vec![[0.0; 3]; 24];
    rots[18] = [0.0, std::f64::consts::FRAC_PI_2, 0.0];
    let m = Motion::new(
        "bend",
        30.0,
        sk.clone(),
        vec![[0.0; 3]],
        rots,
        Labels::new(),
    )
    .unwrap();
    let pos = m.positions();
    let o = sk.offsets[20];
    let d = sub(pos[20], pos[18]);
    let expect = [o[2], o[1], -o[0]];
    for a in 0..3 {
        assert!((d[a] - expect[a]).abs() < 1e-12, "{d:?} vs {expect:?}");
    }
}

#[test]
fn mirror_twice_is_identity() {
    let m = sine_clip(50, 60.0);
    let mm = m.mirror().unwrap().mirror().unwrap();
    for (a, b) in m.rotations.iter().zip(&mm.rotations) {
        assert!(geodesic_axis_angle(*a, *b) < 1e-12);
    }
    for (a, b) in m.trans.iter().zip(&mm.trans) {
        assert!(norm(sub(*a, *b)) < 1e-12);
    }
    let mir = m.mirror().unwrap();
    // The left elbow's swing now lives on the right elbow, z negated.
    let r = mir.rot(10, 19);
    let l = m.rot(10, 18);
    assert!((r[2] + l[2]).abs() < 1e-12 && (r[0] - l[0]).abs() < 1e-12);
}

#[test]
fn resample_down_then_up_keeps_positions_close() {
    let m = sine_clip(121, 60.0);
    let down = m.resample(20.0).unwrap();
    assert_eq!(down.frames(), 41);
    // Every third frame is an exact sample.
    assert_eq!(down.rot(5, 18), m.rot(15, 18));
    let up = down.resample(60.0).unwrap();
    assert_eq!(up.frames(), 121);
    let (a, b) = (m.positions(), up.positions());
    let max = a
        .iter()
        .zip(&b)
        .map(|(x, y)| norm(sub(*x, *y)))
        .fold(0.0, f64::max);
    assert!(max < 0.01, "max position error {max} m");
}

#[test]
fn smpl13_keeps_global_orientation_of_kept_joints() {
    let mut m = sine_clip(5, 30.0);
    // Bend the spine so that folding matters.
    for f in 0..5 {
        m.rotations[f * 24 + 3] = [0.4, 0.0, 0.2];
        m.rotations[f * 24 + 13] = [0.0, 0.3, 0.0];
    }
    let g24 = m.global_quats();
    let s = m.to_smpl13().unwrap();
    let g13 = s.global_quats();
    for f in 0..5 {
        for (i, &k) in SMPL13_FROM_24.iter().enumerate() {
            assert!(geodesic_quat(g24[f * 24 + k], g13[f * 13 + i]) < 1e-12);
        }
    }
}

#[test]
fn normalize_root_faces_plus_z_at_origin() {
    let mut m = sine_clip(10, 30.0);
    for f in 0..10 {
        m.rotations[f * 24] = [0.0, 1.2, 0.0];
        m.trans[f] = add(m.trans[f], [3.0, 0.0, -2.0]);
    }
    let n = m.normalize_root().unwrap();
    let fwd = n.facing(0).unwrap();
    assert!((fwd[2] - 1.0).abs() < 1e-9, "{fwd:?}");
    let p = n.positions();
    assert!(p[0][0].abs() < 1e-9 && p[0][2].abs() < 1e-9);
    assert!((p[0][1] - m.positions()[0][1]).abs() < 1e-12);
}

#[test]
fn bad_values_are_rejected_with_field() {
    let mut m = sine_clip(3, 30.0);
    m.rotations[30][1] = f64::NAN;
    let e = m.validate().unwrap_err().to_string();
    assert!(e.contains("rotations") && e.contains("frame 1"), "{e}");
    assert!(m.cut(2, 2).is_err());
    assert!(m.resample(0.0).is_err());
}

#[test]
fn a_chained_take_goes_on_from_the_pose_and_path_where_the_last_one_ended() {
    let whole = sine_clip(60, 30.0);
    let j = whole.joints();
    let a = whole.cut(0, 30).unwrap();
    // The second take: frames 20..60 of the same clip, turned 100° about y
    // and moved 5 m away, as a second capture of the same move would be.
    let turn = axis_angle_to_quat([0.0, 100f64.to_radians(), 0.0]);
    let tail = whole.cut(20, 60).unwrap();
    let mut rots = tail.rotations.clone();
    for f in 0..tail.frames() {
        rots[f * j] = quat_to_axis_angle(quat_mul(turn, axis_angle_to_quat(rots[f * j])));
    }
    let trans = tail
        .trans
        .iter()
        .map(|&t| add(quat_rotate(turn, t), [5.0, 0.0, -3.0]))
        .collect();
    let b = tail.with_data(trans, rots);
    // No bridge: it enters after its pose nearest frame 29 (its frame 9)
    // and the chain is the whole clip again.
    let c = Motion::chain(&[a.clone(), b.clone()], 0).unwrap();
    assert_eq!(c.frames(), 60);
    for f in 0..60 {
        assert!(norm(sub(c.trans[f], whole.trans[f])) < 1e-9, "frame {f}");
        for k in 0..j {
            let (x, y) = (c.rotations[f * j + k], whole.rotations[f * j + k]);
            assert!(geodesic_axis_angle(x, y) < 1e-9, "frame {f} joint {k}");
        }
    }
    // A 3-frame bridge goes on at the last step's speed and between the
    // two poses.
    let c = Motion::chain(&[a.clone(), b], 3).unwrap();
    assert_eq!(c.frames(), 30 + 3 + 30);
    assert_eq!(c.trans[..30].to_vec(), a.trans);
    let step = sub(a.trans[29], a.trans[28]);
    for f in 30..34 {
        assert!(
            norm(sub(sub(c.trans[f], c.trans[f - 1]), step)) < 1e-9,
            "frame {f}"
        );
    }
    let (ea, eb) = (a.rotations[29 * j + 18], whole.rotations[30 * j + 18]);
    let mid = c.rotations[31 * j + 18];
    assert!(geodesic_axis_angle(mid, ea) <= geodesic_axis_angle(ea, eb) + 1e-9);
    assert!(geodesic_axis_angle(mid, eb) <= geodesic_axis_angle(ea, eb) + 1e-9);
    // Unlike takes are refused, naming the take.
    let other = Motion::new(
        "other",
        60.0,
        Skeleton::smpl24(),
        vec![[0.0; 3]],
        vec![[0.0; 3]; 24],
        Labels::new(),
    )
    .unwrap();
    let e = Motion::chain(&[a, other], 3).unwrap_err().to_string();
    assert!(e.contains("other") && e.contains("frame rate"), "{e}");
}
