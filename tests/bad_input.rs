//! Bad input never panics and always names the file, the field and the
//! reason. Fixtures are built here; corruptions of the real files run when
//! the data is present.

use choreo::motion::io::{read_bytes, ReadOptions};
use choreo::motion::MotionError;
use rand::{Rng, SeedableRng};

fn err(file: &str, bytes: &[u8]) -> String {
    match read_bytes(file, bytes, &ReadOptions::default()) {
        Ok(l) => panic!(
            "{file}: accepted a bad input ({} frames)",
            l.motion.frames()
        ),
        Err(e) => e.to_string(),
    }
}

/// A tiny BVH built by hand: one root and a two-bone leg.
fn tiny_bvh(frames: usize) -> String {
    let mut s = String::from(
        "HIERARCHY\nROOT Hips\n{\n OFFSET 0 90 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n JOINT LeftUpLeg\n {\n  OFFSET 10 -5 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  JOINT LeftLeg\n  {\n   OFFSET 0 -45 0\n   CHANNELS 3 Zrotation Xrotation Yrotation\n   End Site\n   {\n    OFFSET 0 -40 0\n   }\n  }\n }\n JOINT Spine\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 60 0\n  }\n }\n}\nMOTION\n",
    );
    s.push_str(&format!("Frames: {frames}\nFrame Time: 0.0333333\n"));
    for f in 0..frames {
        s.push_str(&format!("0 90 {f} 1 2 3 4 5 6 7 8 9 10 11 12\n"));
    }
    s
}

#[test]
fn tiny_bvh_fixture_is_valid() {
    let l = read_bytes("t.bvh", tiny_bvh(4).as_bytes(), &ReadOptions::default()).unwrap();
    assert_eq!(l.motion.frames(), 4);
    assert_eq!(l.motion.fps, 30.0);
}

#[test]
fn bvh_errors_name_file_field_reason() {
    let good = tiny_bvh(3);
    let cases: Vec<(String, &str)> = vec![
        (good.replace("Frames: 3", "Frames: 4000000000"), "Frames"),
        (good.replace("Frames: 3", "Frames: -1"), "Frames"),
        (good.replace("Frames: 3", "Frames: 4"), "truncated"),
        (good.replace("Frames: 3", "Frames: 2"), "more values"),
        (good.replace("0 90 1 ", "0 inf 1 "), "not finite"),
        (good.replace("0 90 1 ", "0 NaN 1 "), "not finite"),
        (
            good.replace(
                "CHANNELS 3 Zrotation Xrotation Yrotation\n  JOINT",
                "CHANNELS 9 Zrotation Xrotation Yrotation\n  JOINT",
            ),
            "CHANNELS",
        ),
        (good.replace("OFFSET 10 -5 0", "OFFSET 10 -5"), "OFFSET"),
        (
            good.replace("Frame Time: 0.0333333", "Frame Time: -1"),
            "Frame Time",
        ),
        (
            good.replace("JOINT Spine", "JOINT LeftLeg"),
            "appears twice",
        ),
        (good[..good.len() / 3].to_string(), "HIERARCHY"),
        (good[..good.len() - 20].to_string(), "truncated"),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n}\n}\nMOTION".into(),
            "MOTION",
        ),
        (String::from("HIERARCHY\n") + &"{ ".repeat(10), "ROOT"),
        // Found by cargo fuzz: a multi-byte character inside a channel name.
        (
            good.replacen("Xrotation", "\u{1ef}Xrotation", 1),
            "CHANNELS",
        ),
    ];
    for (text, want) in cases {
        let e = err("bad.bvh", text.as_bytes());
        assert!(
            e.starts_with("bad.bvh") && e.contains(want),
            "want '{want}': {e}"
        );
    }
    // Deep nesting is refused, not recursed into.
    let mut deep = String::from(
        "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n",
    );
    for i in 0..300 {
        deep.push_str(&format!(
            "JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
        ));
    }
    let e = err("deep.bvh", deep.as_bytes());
    assert!(e.contains("deep.bvh"), "{e}");
}

#[test]
fn unknown_formats_and_empty_files() {
    for (name, bytes) in [
        ("x.txt", &b"hello"[..]),
        // Content never decides the format: a pickle's first bytes under
        // another name, and a BVH under no extension, are refused.
        ("looks-like-a-pickle.txt", &[0x80, 0x04, 0x95, 0x00][..]),
        ("take", b"HIERARCHY\nROOT r\n{\n"),
        ("empty.bvh", b""),
        ("empty.pkl", b""),
        ("empty.npz", b""),
    ] {
        let e = err(name, bytes);
        assert!(e.starts_with(name), "{e}");
        if !name.contains(".pkl") && !name.contains(".npz") && !name.contains(".bvh") {
            assert!(e.contains("extension"), "{e}");
        }
    }
}

/// numpy-free npz fixture: a zip holding hand-written .npy arrays.
fn npz(entries: &[(&str, &[usize], &[f64])]) -> Vec<u8> {
    use std::io::Write;
    let mut out = std::io::Cursor::new(Vec::new());
    let mut zw = zip::ZipWriter::new(&mut out);
    for (name, shape, data) in entries {
        zw.start_file(
            format!("{name}.npy"),
            zip::write::SimpleFileOptions::default(),
        )
        .unwrap();
        let a = choreo::motion::io::npy::NdArray {
            shape: shape.to_vec(),
            data: data.to_vec(),
        };
        zw.write_all(&a.to_npy(false)).unwrap();
    }
    zw.finish().unwrap();
    out.into_inner()
}

#[test]
fn npz_errors_name_the_array() {
    let poses = vec![0.0; 2 * 156];
    let trans = vec![0.0; 6];
    let ok = npz(&[
        ("poses", &[2, 156], &poses),
        ("trans", &[2, 3], &trans),
        ("mocap_framerate", &[], &[60.0]),
    ]);
    assert_eq!(
        read_bytes("ok.npz", &ok, &ReadOptions::default())
            .unwrap()
            .motion
            .frames(),
        2
    );
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (
            npz(&[
                ("trans", &[2, 3], &trans),
                ("mocap_framerate", &[], &[60.0]),
            ]),
            "poses",
        ),
        (
            npz(&[
                ("poses", &[2, 156], &poses),
                ("mocap_framerate", &[], &[60.0]),
            ]),
            "trans",
        ),
        (
            npz(&[("poses", &[2, 156], &poses), ("trans", &[2, 3], &trans)]),
            "mocap_framerate",
        ),
        (
            npz(&[
                ("poses", &[2, 10], &poses[..20]),
                ("trans", &[2, 3], &trans),
                ("mocap_framerate", &[], &[60.0]),
            ]),
            "poses",
        ),
        (
            npz(&[
                ("poses", &[2, 156], &poses),
                ("trans", &[3, 2], &trans),
                ("mocap_framerate", &[], &[60.0]),
            ]),
            "trans",
        ),
        (
            npz(&[
                ("poses", &[2, 156], &poses),
                ("trans", &[2, 3], &trans),
                ("mocap_framerate", &[], &[0.0]),
            ]),
            "fps",
        ),
        (
            npz(&[
                ("poses", &[2, 156], &poses),
                ("trans", &[2, 3], &[0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0]),
                ("mocap_framerate", &[], &[60.0]),
            ]),
            "trans",
        ),
        (ok[..ok.len() / 2].to_vec(), "npz"),
    ];
    for (bytes, want) in cases {
        let e = err("bad.npz", &bytes);
        assert!(
            e.starts_with("bad.npz") && e.contains(want),
            "want '{want}': {e}"
        );
    }
}

/// Seeded byte-level mutations (flips, truncations, insertions) of each
/// format: every outcome is Ok or a MotionError naming the file — no panic.
fn mutate_many(name: &str, good: &[u8], rounds: usize) -> (usize, usize) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(42);
    let (mut ok, mut errs) = (0, 0);
    for _ in 0..rounds {
        let mut b = good.to_vec();
        match rng.gen_range(0..4) {
            0 => {
                for _ in 0..rng.gen_range(1..8) {
                    let i = rng.gen_range(0..b.len());
                    b[i] = rng.gen();
                }
            }
            1 => b.truncate(rng.gen_range(0..b.len())),
            2 => {
                let i = rng.gen_range(0..b.len());
                let junk: Vec<u8> = (0..rng.gen_range(1..16)).map(|_| rng.gen()).collect();
                b.splice(i..i, junk);
            }
            _ => {
                let i = rng.gen_range(0..b.len());
                b[i] = b"0123456789.-e \n{}"[rng.gen_range(0..17)];
            }
        }
        let r = std::panic::catch_unwind(|| read_bytes(name, &b, &ReadOptions::default()));
        match r {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(e)) => {
                let s = e.to_string();
                assert!(s.starts_with(name), "error without file name: {s}");
                if let MotionError::Invalid { field, .. } = &e {
                    assert!(!field.is_empty());
                }
                errs += 1;
            }
            Err(_) => panic!("{name}: reader panicked on a mutated input"),
        }
    }
    (ok, errs)
}

#[test]
fn mutated_inputs_never_panic() {
    let (o, e) = mutate_many("m.bvh", tiny_bvh(5).as_bytes(), 3000);
    eprintln!("bvh fixture: {o} mutations still valid, {e} rejected");
    let poses = vec![0.1; 3 * 156];
    let good = npz(&[
        ("poses", &[3, 156], &poses),
        ("trans", &[3, 3], &[0.0; 9]),
        ("mocap_framerate", &[], &[30.0]),
    ]);
    let (o, e) = mutate_many("m.npz", &good, 3000);
    eprintln!("npz fixture: {o} still valid, {e} rejected");
    if let Some(p) = choreo::data::require("aistpp/motions/gBR_sBM_cAll_d04_mBR2_ch08.pkl") {
        let bytes = std::fs::read(p).unwrap();
        let (o, e) = mutate_many("m.pkl", &bytes, 1500);
        eprintln!("AIST++ pickle: {o} still valid, {e} rejected");
    }
}

#[test]
fn real_pickle_corruptions_are_named() {
    let Some(p) = choreo::data::require("aistpp/motions/gBR_sBM_cAll_d04_mBR2_ch08.pkl") else {
        return;
    };
    let good = std::fs::read(p).unwrap();
    let patch = |from: &[u8], to: &[u8]| -> Vec<u8> {
        let i = good
            .windows(from.len())
            .position(|w| w == from)
            .expect("pattern in pickle");
        let mut b = good.clone();
        b[i..i + to.len()].copy_from_slice(to);
        b
    };
    let e = err("x.pkl", &patch(b"smpl_trans", b"smpl_trazz"));
    assert!(e.contains("smpl_trans") && e.contains("missing"), "{e}");
    // Shape (576, 72) -> (575, 72): the data no longer matches.
    let e = err(
        "x.pkl",
        &patch(&[b'M', 0x40, 0x02, b'K', 72], &[b'M', 0x3f, 0x02, b'K', 72]),
    );
    assert!(e.contains("pickle") && e.contains("bytes"), "{e}");
    // A NaN in the poses.
    let i = good
        .windows(2)
        .position(|w| w == [b'B', 0x00])
        .unwrap_or(182)
        + 5;
    let mut b = good.clone();
    b[i..i + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = err("x.pkl", &b);
    assert!(e.contains("smpl_poses") && e.contains("NaN"), "{e}");
    let e = err("x.pkl", &good[..good.len() - 10]);
    assert!(e.contains("truncated"), "{e}");
}
