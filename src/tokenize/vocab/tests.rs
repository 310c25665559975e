//! Tests of `tokenize/vocab.rs`.

use super::*;
use crate::motion::rotation::geodesic_axis_angle;

fn vocab() -> Vocabulary {
    let mut labels = BTreeMap::new();
    labels.insert(
        "genre".to_string(),
        ["gBR", "gPO"].iter().map(|s| s.to_string()).collect(),
    );
    labels.insert(
        "dancer".to_string(),
        ["d01"].iter().map(|s| s.to_string()).collect(),
    );
    Vocabulary::new(labels)
}

/// 13-joint clip at 20 fps: the root walks 1 m/s along +x at 0.9 m, the
/// left elbow swings.
fn walk(frames: usize) -> Motion {
    let sk = Skeleton::smpl13();
    let o = sk.offsets[0];
    let mut rots = vec![[0.0; 3]; frames * 13];
    for f in 0..frames {
        rots[f * 13 + 9] = [0.0, 0.0, 0.8 * (f as f64 * 0.3).sin()];
    }
    let trans = (0..frames)
        .map(|f| [f as f64 / 20.0 - o[0], 0.9 - o[1], -o[2]])
        .collect();
    Motion::new("walk", 20.0, sk, trans, rots, Labels::new()).unwrap()
}

#[test]
fn a_given_floor_moves_heights_and_nothing_else() {
    let v = vocab();
    let m = walk(10);
    let (own, floor) = v.encode_motion_on_floor(&m, None).unwrap();
    assert_eq!(own, v.encode_motion(&m).unwrap());
    // A floor 0.5 m lower: every height token rises by 0.5 m of bins,
    // every other slot is unchanged; a higher floor is ignored.
    let (low, used) = v.encode_motion_on_floor(&m, Some(floor - 0.5)).unwrap();
    assert!((used - (floor - 0.5)).abs() < 1e-12);
    let step = (v.height_range[1] - v.height_range[0]) / v.bins as f64;
    let fl = v.frame_len();
    for (i, (a, b)) in own.iter().zip(&low).enumerate() {
        if i % fl == fl - 2 {
            assert_eq!(*b as f64 - *a as f64, (0.5 / step).round(), "slot {i}");
        } else {
            assert_eq!(a, b, "slot {i}");
        }
    }
    let (high, used) = v.encode_motion_on_floor(&m, Some(floor + 1.0)).unwrap();
    assert_eq!((high, used), (own, floor));
}

#[test]
fn layout_and_ids() {
    let v = vocab();
    assert_eq!(v.frame_len(), 43);
    assert_eq!(v.size(), 360 + 4 + 2 + 3);
    assert_eq!(v.class_token("dancer").unwrap(), 364);
    assert_eq!(v.class_token("genre").unwrap(), 365);
    assert_eq!(v.label_token("dancer", "d01").unwrap(), 366);
    assert_eq!(v.label_token("genre", "gPO").unwrap(), 368);
    assert!(v
        .label_token("genre", "gXX")
        .unwrap_err()
        .to_string()
        .contains("not seen"));
    assert!(v.class_token("style").is_err());
    for id in 0..v.size() as u32 {
        assert!(v.token(id).is_some(), "{id}");
    }
    assert_eq!(v.token(v.size() as u32), None);
    assert_eq!(v.token_name(368), "<genre=gPO>");
    assert_eq!(v.allowed(42), 360..361);
    assert_eq!(v.allowed(5), 0..360);
    let back = Vocabulary::from_json(&v.to_json(), "v.json").unwrap();
    assert_eq!(back, v);
    let mut bad = v.clone();
    bad.bins = 1;
    assert!(Vocabulary::from_json(&bad.to_json(), "v.json").is_err());
}

#[test]
fn a_walk_round_trips_through_tokens() {
    let v = vocab();
    let m = walk(40);
    let toks = v.encode_motion(&m).unwrap();
    assert_eq!(toks.len(), 40 * 43);
    let mut labels = Labels::new();
    labels.insert("genre".into(), "gBR".into());
    let mut stream = v.prefix(&labels).unwrap();
    stream.extend(&toks);
    stream.extend(&toks[..10]); // a partial frame is dropped
    let d = v.decode_motion(&stream, "walk").unwrap();
    assert_eq!(d.frames(), 40);
    // Half a 1° bin per component at most → well under 1° per joint.
    for f in 0..40 {
        for k in 0..13 {
            let g = geodesic_axis_angle(m.rot(f, k), d.rot(f, k));
            assert!(g < 0.5f64.to_radians() * 3f64.sqrt() + 1e-9, "{f} {k} {g}");
        }
    }
    // The root walks 1 m/s: 39 steps of 5 cm, each off by < half a bin.
    let (a, b) = (m.positions(), d.positions());
    let dx = |p: &Vec<Vec3>| p[39 * 13][0] - p[0][0];
    let half = 8.0 / 360.0 / 2.0 / 20.0;
    assert!((dx(&a) - dx(&b)).abs() <= 39.0 * half + 1e-9);
    // Heights are measured from the clip's lowest joint, so the decoded
    // clip's floor is at 0 and its shape matches.
    let floor = |p: &Vec<Vec3>| p.iter().map(|q| q[1]).fold(f64::INFINITY, f64::min);
    assert!(floor(&b).abs() < 2.5 / 360.0);
    assert!(((a[0][1] - floor(&a)) - (b[0][1] - floor(&b))).abs() < 2.5 / 360.0);
}

#[test]
fn bad_streams_are_errors() {
    let v = vocab();
    let toks = v.encode_motion(&walk(3)).unwrap();
    assert!(v.decode_motion(&toks[..42], "x").is_err());
    let mut t = toks.clone();
    t[42] = 5;
    let e = v.decode_motion(&t, "x").unwrap_err().to_string();
    assert!(e.contains("frame 0, slot 42"), "{e}");
    let mut t = toks.clone();
    t[50] = v.sep();
    assert!(v.decode_motion(&t, "x").is_err());
    let mut l = Labels::new();
    l.insert("music".into(), "mBR0".into());
    assert!(v.prefix(&l).is_err());
}

/// A walk forward at 1.2 m/s with the body facing `yaw` (about +y), the
/// pelvis also tilted 0.2 rad about its own sideways axis, turning
/// `turn` rad a frame.
fn walk_facing(yaw: f64, turn: f64, frames: usize) -> Motion {
    use crate::motion::rotation::{axis_quat, quat_mul, quat_to_axis_angle, Axis};
    let sk = Skeleton::smpl13();
    let o = sk.offsets[0];
    let mut rots = vec![[0.0; 3]; frames * 13];
    let (mut x, mut z) = (0.0, 0.0);
    let mut trans = Vec::new();
    for f in 0..frames {
        let h = yaw + turn * f as f64;
        let q = quat_mul(axis_quat(Axis::Y, h), axis_quat(Axis::X, 0.2));
        rots[f * 13] = quat_to_axis_angle(q);
        if f > 0 {
            x += 1.2 / 20.0 * h.sin();
            z += 1.2 / 20.0 * h.cos();
        }
        trans.push([x - o[0], 0.9 - o[1], z - o[2]]);
    }
    Motion::new("walk", 20.0, sk, trans, rots, Labels::new()).unwrap()
}

#[test]
fn heading_velocity_is_the_same_tokens_whichever_way_the_body_faces() {
    let mut v = vocab();
    v.root_velocity = RootVelocity::Heading;
    let nj = v.joints.len();
    let fl = v.frame_len();
    let forward = v.encode_root_velocity(1.2);
    let still = v.encode_root_velocity(0.0);
    for yaw in [0.0, 0.7, -2.0, 3.0] {
        let m = walk_facing(yaw, 0.0, 12);
        let t = v.encode_motion(&m).unwrap();
        for f in 1..12 {
            let w = &t[f * fl..(f + 1) * fl];
            // Sideways still, forward 1.2 m/s (±1 bin for the pelvis's
            // quantised heading).
            assert!(w[3 * nj].abs_diff(still) <= 1, "{yaw} {f}");
            assert!(w[3 * nj + 1].abs_diff(forward) <= 1, "{yaw} {f}");
        }
        // In the scene's axes the same walk is a different pair per yaw.
        let world = vocab().encode_motion(&m).unwrap();
        let (wx, _) = vocab().root_velocity_tokens(&world[fl..2 * fl]);
        assert_eq!(wx, vocab().encode_root_velocity(1.2 * yaw.sin()));
    }
}

#[test]
fn heading_velocity_decodes_to_the_same_path_as_world() {
    // A walk that turns 2° a frame: both layouts rebuild the path to
    // within their quantisation.
    let m = walk_facing(0.4, 2f64.to_radians(), 60);
    let mut h = vocab();
    h.root_velocity = RootVelocity::Heading;
    let json = h.to_json();
    assert!(json.contains("\"root_velocity\": \"heading\""), "{json}");
    assert!(!vocab().to_json().contains("root_velocity"));
    let back = Vocabulary::from_json(&json, "v").unwrap();
    assert_eq!(back.root_velocity, RootVelocity::Heading);
    let a = m.positions();
    for v in [vocab(), h] {
        let d = v.decode_motion(&v.encode_motion(&m).unwrap(), "w").unwrap();
        let b = d.positions();
        for f in [20, 40, 59] {
            let (p, q) = (a[f * 13], b[f * 13]);
            let off =
                ((p[0] - a[0][0]) - (q[0] - b[0][0])).hypot((p[2] - a[0][2]) - (q[2] - b[0][2]));
            // 59 steps, each off by under a bin (2.2 cm/s → 1.1 mm) plus
            // the heading's quantisation (½° of 6 cm).
            assert!(off < 0.04, "{:?} frame {f}: {off}", v.root_velocity);
        }
    }
}

#[test]
fn a_lying_body_still_has_a_heading() {
    // Forward axis straight down (face to the floor): the heading comes
    // from the sideways axis.
    use crate::motion::rotation::{axis_quat, quat_mul, quat_to_axis_angle, Axis};
    for yaw in [0.0f64, 1.0, -2.5] {
        let q = quat_mul(
            axis_quat(Axis::Y, yaw),
            axis_quat(Axis::X, std::f64::consts::FRAC_PI_2),
        );
        let h = heading_of(quat_to_axis_angle(q));
        let d = (h - yaw).rem_euclid(std::f64::consts::TAU);
        assert!(d < 1e-9 || (std::f64::consts::TAU - d) < 1e-9, "{yaw} {h}");
    }
}
