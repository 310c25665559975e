//! Tests of `motion/io/bvh.rs`.

use super::*;

const TINY: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 90 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT LeftUpLeg
  {
    OFFSET 10 -5 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT LeftLeg
    {
      OFFSET 0 -45 0
      CHANNELS 3 Xrotation Yrotation Zrotation
      End Site
      {
        OFFSET 0 -40 0
      }
    }
  }
  JOINT RightUpLeg
  {
    OFFSET -10 -5 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT RightLeg
    {
      OFFSET 0 -45 0
      CHANNELS 3 Xrotation Yrotation Zrotation
      End Site
      {
        OFFSET 0 -40 0
      }
    }
  }
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Head
    {
      OFFSET 0 60 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 15 0
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.033333
1 90 2 0 0 0 0 0 0 90 0 0 0 0 0 0 0 0 0 0 0 0 0 0
1 91 3 10 20 30 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
";

fn read(text: &str) -> Result<BvhMotion, MotionError> {
    read_bvh(
        "tiny.bvh",
        text,
        &BvhReadOptions {
            metres_per_unit: Some(0.01),
        },
    )
}

#[test]
fn reads_tiny_file_by_hand() {
    let b = read(TINY).unwrap();
    let m = &b.motion;
    assert_eq!(m.frames(), 2);
    assert_eq!(m.joints(), 7);
    assert_eq!(m.fps, 30.0);
    let p = m.positions();
    // Frame 0: root at (0.01, 0.90, 0.02) m; knee bent 90° about x, so
    // the shin (0, -0.40) points along -z... Rx(90°) maps -y to -z.
    assert!(norm(sub(p[0], [0.01, 0.90, 0.02])) < 1e-12);
    let knee = p[2];
    assert!(norm(sub(knee, [0.11, 0.40, 0.02])) < 1e-12, "{knee:?}");
}

#[test]
fn write_then_read_is_exact_to_precision() {
    let b = read(TINY).unwrap();
    let text = write_bvh(
        &b.motion,
        &BvhWriteOptions {
            layout: Some(&b.layout),
            ..Default::default()
        },
    )
    .unwrap();
    let back = read(&text).unwrap().motion;
    let (a, c) = (b.motion.positions(), back.positions());
    for (x, y) in a.iter().zip(&c) {
        assert!(norm(sub(*x, *y)) < 1e-8);
    }
    for (x, y) in b.motion.rotations.iter().zip(&back.rotations) {
        assert!(geodesic_axis_angle(*x, *y) < 1e-7);
    }
}

#[test]
fn bad_files_name_field() {
    let cases = [
        ("", "HIERARCHY"),
        ("HIERARCHY ROOT a { OFFSET 0 0", "OFFSET"),
        (&TINY.replace("Frames: 2", "Frames: 99999999999"), "Frames"),
        (&TINY.replace("Frames: 2", "Frames: 3"), "truncated"),
        (
            &TINY.replace("Frame Time: 0.033333", "Frame Time: 0"),
            "Frame Time",
        ),
        (&TINY.replace("1 91 3", "1 nan 3"), "MOTION"),
        (
            &TINY.replace(
                "Zrotation Xrotation Yrotation\n  JOINT LeftUpLeg",
                "Zrotation Xrotation Wrotation\n  JOINT LeftUpLeg",
            ),
            "CHANNELS",
        ),
        (&TINY[..TINY.len() - 30], "truncated"),
    ];
    for (text, want) in cases {
        let e = read(text)
            .err()
            .unwrap_or_else(|| panic!("accepted: {want}"))
            .to_string();
        assert!(e.contains(want) && e.contains("tiny.bvh"), "{want}: {e}");
    }
}
