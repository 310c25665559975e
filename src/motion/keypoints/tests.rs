//! Tests of `motion/keypoints/mod.rs`.

use super::*;
use crate::motion::clip::Labels;

fn bent_motion() -> Motion {
    // A body with bent knees and elbows, a turned pelvis and a bent spine.
    let mut rots = vec![[0.0; 3]; 24 * 3];
    for f in 0..3 {
        let t = f as f64 * 0.2;
        rots[f * 24] = [0.2 + t, 0.5, 0.1];
        rots[f * 24 + 1] = [-0.6, 0.1, 0.2];
        rots[f * 24 + 2] = [-0.3, -0.1, -0.1];
        for (j, a) in [(4, 1.0), (5, 0.7)] {
            rots[f * 24 + j] = scale(normalize(KNEE_AXIS[j - 4]).unwrap(), a + t);
        }
        for (j, a) in [(18, 1.2), (19, 0.8)] {
            rots[f * 24 + j] = scale(normalize(ELBOW_AXIS[j - 18]).unwrap(), a);
        }
        rots[f * 24 + 16] = [0.1, 0.3, -0.8];
        rots[f * 24 + 17] = [0.0, -0.2, 0.9];
        for j in SPINE {
            rots[f * 24 + j] = [0.1, 0.05, 0.0];
        }
    }
    Motion::new(
        "bent",
        30.0,
        Skeleton::smpl24(),
        vec![[0.1, 0.9, -0.2]; 3],
        rots,
        Labels::new(),
    )
    .unwrap()
}

#[test]
fn up_axes_turn_onto_y() {
    for (up, v) in [
        (Up::Y, [0.0, 1.0, 0.0]),
        (Up::NegY, [0.0, -1.0, 0.0]),
        (Up::Z, [0.0, 0.0, 1.0]),
        (Up::NegZ, [0.0, 0.0, -1.0]),
        (Up::X, [1.0, 0.0, 0.0]),
        (Up::NegX, [-1.0, 0.0, 0.0]),
    ] {
        let r = quat_rotate(up.to_y_up(), v);
        assert!(norm(sub(r, [0.0, 1.0, 0.0])) < 1e-12, "{up}: {r:?}");
        assert_eq!(up.name().parse::<Up>().unwrap(), up);
    }
}

#[test]
fn clean_keypoints_give_back_the_bone_directions() {
    let m = bent_motion();
    for layout in [Layout::H36m17, Layout::Mediapipe33] {
        let mut o = SynthOptions::clean(layout, 30.0);
        o.units_per_metre = 1000.0;
        let kp = synthesize(&m, &o).unwrap();
        let o = SolveOptions {
            smooth_s: 0.0,
            ..SolveOptions::new(layout)
        };
        let (solved, rep) = solve("bent", &kp, &o).unwrap();
        assert!((rep.metres_per_unit - 0.001).abs() < 1e-9, "{rep:?}");
        assert_eq!(rep.flagged_frames, 0);
        // Hinge joints come back exactly (their parents' twist is fixed
        // by the bend); every limb bone points where it pointed.
        for (name, errs) in joint_errors(layout, &solved, &m, Measure::ParentFrame) {
            let worst = errs.iter().cloned().fold(0.0, f64::max);
            if name.contains("Knee") || name.contains("Elbow") {
                assert!(worst < 0.5, "{layout} {name}: {worst:.3}°");
            }
        }
        let (ps, pt) = (solved.positions(), m.positions());
        for f in 0..3 {
            for (a, b) in [
                (1, 4),
                (4, 7),
                (2, 5),
                (5, 8),
                (16, 18),
                (18, 20),
                (17, 19),
                (19, 21),
            ] {
                let u = normalize(sub(ps[f * 24 + b], ps[f * 24 + a])).unwrap();
                let v = normalize(sub(pt[f * 24 + b], pt[f * 24 + a])).unwrap();
                let deg = dot(u, v).clamp(-1.0, 1.0).acos().to_degrees();
                assert!(deg < 0.5, "{layout} bone {a}->{b}: {deg:.3}°");
            }
        }
        // The pelvis point lands where its keypoint is (H36M's is the
        // root joint; MediaPipe's the hips' midpoint).
        let (ps, pt) = (solved.positions(), m.positions());
        let mid = |p: &[Vec3], ids: &[usize]| mean_of(p, ids);
        let ids: &[usize] = match layout {
            Layout::H36m17 => &[0],
            Layout::Mediapipe33 => &[1, 2],
        };
        let d = norm(sub(mid(&ps[..24], ids), mid(&pt[..24], ids)));
        assert!(d < 1e-6, "{layout}: pelvis point off by {d} m");
    }
}

#[test]
fn gaps_are_bridged_and_too_many_refused() {
    let m = bent_motion();
    let mut kp = synthesize(&m, &SynthOptions::clean(Layout::H36m17, 30.0)).unwrap();
    for p in &mut kp.points[17..34] {
        *p = [f64::NAN; 3];
    }
    let o = SolveOptions::new(Layout::H36m17);
    let (solved, rep) = solve("gap", &kp, &o).unwrap();
    assert_eq!(rep.gaps, vec![[1, 1]]);
    let a = axis_angle_to_quat(solved.rot(0, 4));
    let c = axis_angle_to_quat(solved.rot(2, 4));
    let mid = axis_angle_to_quat(solved.rot(1, 4));
    assert!(geodesic_quat(mid, slerp(a, c, 0.5)) < 1e-9);
    for p in &mut kp.points[..17] {
        *p = [f64::NAN; 3];
    }
    let e = solve("gap", &kp, &o).unwrap_err().to_string();
    assert!(
        e.contains("gap: field `frames`") && e.contains("2 of 3"),
        "{e}"
    );
}
