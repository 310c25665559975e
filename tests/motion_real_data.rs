//! The motion core on the real files in `CHOREO_DATA` (default
//! `../shared/data`). Each test skips with a printed reason when the data is
//! absent, and fails instead when `CHOREO_REQUIRE_DATA=1` (CI).

use choreo::data::{files_with_ext, require};
use choreo::motion::io::{self, bvh, ReadOptions};
use choreo::motion::retarget::{bone_direction_error, retarget_to_smpl13, JointMap};
use choreo::motion::rotation::*;
use choreo::motion::Motion;
use std::collections::BTreeMap;
use std::path::Path;

fn load(p: &Path) -> io::Loaded {
    io::read_path(p, &ReadOptions::default()).unwrap_or_else(|e| panic!("{e}"))
}

/// Largest joint position difference, joints matched by name (a BVH
/// round trip lists joints depth-first).
fn max_pos_err(a: &Motion, b: &Motion) -> f64 {
    assert_eq!(a.frames(), b.frames());
    let (pa, pb) = (a.positions(), b.positions());
    let (ja, jb) = (a.joints(), b.joints());
    let mut worst = 0.0f64;
    for (i, name) in a.skeleton.names.iter().enumerate() {
        let k = b
            .skeleton
            .index_of(name)
            .unwrap_or_else(|| panic!("joint {name} lost"));
        for f in 0..a.frames() {
            worst = worst.max(norm(sub(pa[f * ja + i], pb[f * jb + k])));
        }
    }
    worst
}

fn retargeted(p: &Path) -> Motion {
    let src = load(p).motion;
    let map = JointMap::resolve(&src.skeleton, &BTreeMap::new()).unwrap();
    retarget_to_smpl13(&src, &map).unwrap()
}

const AIST: [(&str, usize); 4] = [
    ("gBR_sBM_cAll_d04_mBR2_ch08", 576),
    ("gBR_sBM_cAll_d06_mBR2_ch06", 576),
    ("gJS_sBM_cAll_d03_mJS2_ch07", 576),
    ("gJS_sFM_cAll_d02_mJS4_ch09", 1919),
];

#[test]
fn aist_pickles_load_with_fps_frames_labels() {
    let Some(dir) = require("aistpp/motions") else {
        return;
    };
    for (name, frames) in AIST {
        let m = load(&dir.join(format!("{name}.pkl"))).motion;
        assert_eq!(m.fps, 60.0);
        assert_eq!(m.frames(), frames, "{name}");
        assert_eq!(m.joints(), 24);
        let g = &name[1..3];
        assert_eq!(m.labels["genre"], g);
        assert_eq!(m.labels["dancer"], name.split('_').nth(3).unwrap());
        assert_eq!(
            m.labels["tempo_bpm"],
            if name.contains("mJS4") { "120" } else { "100" }
        );
    }
}

/// Forward kinematics gives a human body: pelvis-to-head 0.35–0.70 m (SMPL
/// rest: 0.58 m), ankle-to-ankle 0.01–1.20 m on every frame; the lowest joint
/// sits within 0.25 m of the sequence's floor (its 5th-percentile lowest
/// joint height) on every frame and never sinks 0.10 m below it.
#[test]
fn aist_forward_kinematics_is_a_plausible_body() {
    let Some(dir) = require("aistpp/motions") else {
        return;
    };
    for (name, _) in AIST {
        let m = load(&dir.join(format!("{name}.pkl"))).motion;
        let sk = &m.skeleton;
        let (pelvis, head) = (sk.index_of("Pelvis").unwrap(), sk.index_of("Head").unwrap());
        let (la, ra) = (
            sk.index_of("Left_Ankle").unwrap(),
            sk.index_of("Right_Ankle").unwrap(),
        );
        let p = m.positions();
        let j = m.joints();
        let mut lows = Vec::new();
        for f in 0..m.frames() {
            let fr = &p[f * j..(f + 1) * j];
            let ph = norm(sub(fr[head], fr[pelvis]));
            assert!(
                (0.35..0.70).contains(&ph),
                "{name} frame {f}: pelvis-head {ph}"
            );
            let aa = norm(sub(fr[la], fr[ra]));
            assert!(
                (0.01..1.20).contains(&aa),
                "{name} frame {f}: ankle-ankle {aa}"
            );
            lows.push(fr.iter().map(|v| v[1]).fold(f64::INFINITY, f64::min));
        }
        let mut sorted = lows.clone();
        sorted.sort_by(f64::total_cmp);
        let floor = sorted[sorted.len() / 20];
        for (f, l) in lows.iter().enumerate() {
            assert!(
                *l > floor - 0.10 && *l < floor + 0.25,
                "{name} frame {f}: lowest joint {l} vs floor {floor}"
            );
        }
    }
}

#[test]
fn aist_to_bvh_and_back_within_a_millimetre() {
    let Some(dir) = require("aistpp/motions") else {
        return;
    };
    for (name, _) in AIST {
        let m = load(&dir.join(format!("{name}.pkl"))).motion;
        let text = bvh::write_bvh(&m, &bvh::BvhWriteOptions::default()).unwrap();
        let back = bvh::read_bvh("back.bvh", &text, &bvh::BvhReadOptions::default())
            .unwrap()
            .motion;
        assert_eq!(back.fps, 60.0);
        let e = max_pos_err(&m, &back);
        assert!(e < 1e-3, "{name}: {e} m");
        eprintln!(
            "{name}: AIST++ -> BVH -> read max joint position error {:.2e} m",
            e
        );
    }
}

#[test]
fn all_bandai_takes_load_with_labels() {
    let Some(dir) = require("bandai") else { return };
    let files = files_with_ext(&dir, &["bvh"]);
    assert_eq!(files.len(), 524);
    for f in &files {
        let l = load(f);
        let m = &l.motion;
        assert_eq!(m.fps, 30.0, "{}", f.display());
        let stem = f.file_stem().unwrap().to_str().unwrap();
        let parts: Vec<&str> = stem.split('_').collect();
        assert_eq!(m.labels["content"], parts[1]);
        assert_eq!(m.labels["style"], parts[2]);
        // The moving `joint_Root` is folded into `Hips`.
        assert_eq!(m.skeleton.names[0], "Hips");
        assert!(m.frames() > 10);
    }
}

#[test]
fn cmu_01_01_loads() {
    let Some(p) = require("cmu/01_01.bvh") else {
        return;
    };
    let m = load(&p).motion;
    assert_eq!(m.fps, 120.0);
    assert_eq!(m.frames(), 2752);
    assert_eq!(m.joints(), 31);
    // CMU units detected: head joint to lowest joint 1.3–2.0 m at frame 0.
    let p0 = m.cut(0, 1).unwrap().positions();
    let ys: Vec<f64> = p0.iter().map(|v| v[1]).collect();
    let h =
        ys.iter().cloned().fold(f64::MIN, f64::max) - ys.iter().cloned().fold(f64::MAX, f64::min);
    assert!((1.3..2.0).contains(&h), "height {h}");
}

/// BVH → BVH keeps every joint position to 1e-5 m and rotation to 1e-6 rad
/// (the Bandai files carry 6 significant digits: 0.001 cm, 0.0001°).
#[test]
fn bvh_to_bvh_is_exact_to_file_precision() {
    let Some(root) = require("bandai") else {
        return;
    };
    let mut files = files_with_ext(&root, &["bvh"])
        .into_iter()
        .step_by(50)
        .collect::<Vec<_>>();
    if let Some(c) = require("cmu/01_01.bvh") {
        files.push(c);
    }
    for f in files {
        let l = load(&f);
        let opts = bvh::BvhWriteOptions {
            metres_per_unit: l.bvh_layout.as_ref().unwrap().metres_per_unit,
            layout: l.bvh_layout.as_ref(),
            ..Default::default()
        };
        let text = bvh::write_bvh(&l.motion, &opts).unwrap();
        let back = bvh::read_bvh(
            "back.bvh",
            &text,
            &bvh::BvhReadOptions {
                metres_per_unit: Some(opts.metres_per_unit),
            },
        )
        .unwrap()
        .motion;
        let e = max_pos_err(&l.motion, &back);
        let r = l
            .motion
            .rotations
            .iter()
            .zip(&back.rotations)
            .map(|(a, b)| geodesic_axis_angle(*a, *b))
            .fold(0.0, f64::max);
        assert!(e < 1e-5 && r < 1e-6, "{}: {e} m, {r} rad", f.display());
    }
}

#[test]
fn mirror_twice_is_identity_on_real_data() {
    let Some(a) = require("aistpp/motions/gJS_sFM_cAll_d02_mJS4_ch09.pkl") else {
        return;
    };
    let Some(b) = require("bandai/dataset-2/dataset-2_wave-left-hand_feminine_002.bvh") else {
        return;
    };
    // Bandai's rig turns its right-side joint frames, so it is mirrored on
    // the retargeted SMPL-13 body; its raw skeleton is refused.
    assert!(load(&b).motion.mirror().is_err());
    for m in [load(&a).motion, retargeted(&b)] {
        let mm = m.mirror().unwrap().mirror().unwrap();
        assert!(max_pos_err(&m, &mm) < 1e-9);
        // One mirror moves a one-sided motion.
        assert!(max_pos_err(&m, &m.mirror().unwrap()) > 0.05);
    }
}

/// A left-hand wave mirrored waves the right hand: the right wrist's path
/// after mirroring is the left wrist's path reflected.
#[test]
fn mirrored_bandai_wave_swaps_hands() {
    let Some(p) = require("bandai/dataset-2/dataset-2_wave-left-hand_feminine_002.bvh") else {
        return;
    };
    let m = retargeted(&p);
    let axis = Motion::lateral_axis(&m.skeleton).unwrap();
    assert_eq!(axis, 0);
    let mir = m.mirror().unwrap();
    let (l, r) = (
        m.skeleton.index_of("Left_Wrist").unwrap(),
        m.skeleton.index_of("Right_Wrist").unwrap(),
    );
    let (pa, pb) = (m.positions(), mir.positions());
    let j = m.joints();
    for f in 0..m.frames() {
        let mut refl = pa[f * j + l];
        refl[axis] = -refl[axis];
        // SMPL's left and right bones differ by up to a few millimetres.
        assert!(norm(sub(refl, pb[f * j + r])) < 0.02, "frame {f}");
    }
}

/// 60 → 20 → 60 fps: mean joint error under 10 mm and 99th percentile under
/// 100 mm (SLERP cannot bring back motion above 10 Hz that 20 fps drops). The
/// maximum is not bounded: AIST++ has one-frame capture flips (frame 203 of
/// gBR_sBM_cAll_d04_mBR2_ch08 turns the root 85° and the right knee 171° for
/// a single frame), which any 20 fps sampling misses.
#[test]
fn resample_60_20_60_error_is_bounded() {
    let Some(dir) = require("aistpp/motions") else {
        return;
    };
    for (name, _) in AIST {
        let m = load(&dir.join(format!("{name}.pkl"))).motion;
        let back = m.resample(20.0).unwrap().resample(60.0).unwrap();
        let n = back.frames().min(m.frames());
        let (a, b) = (
            m.cut(0, n).unwrap().positions(),
            back.cut(0, n).unwrap().positions(),
        );
        let errs: Vec<f64> = a.iter().zip(&b).map(|(x, y)| norm(sub(*x, *y))).collect();
        let mut sorted = errs.clone();
        sorted.sort_by(f64::total_cmp);
        let max = sorted[sorted.len() - 1];
        let p99 = sorted[sorted.len() * 99 / 100];
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        eprintln!(
            "{name}: 60->20->60 fps joint error mean {:.2} mm, p99 {:.1} mm, max {:.1} mm",
            mean * 1e3,
            p99 * 1e3,
            max * 1e3
        );
        assert!(mean < 0.010 && p99 < 0.100, "{name}: mean {mean} p99 {p99}");
    }
}

/// Retargeting Bandai and CMU onto the 13-joint subset: every limb bone
/// points where the source's does (within 0.01°), the body faces +z after
/// root normalisation, and knees sit below hips when standing.
#[test]
fn retarget_bandai_and_cmu_to_smpl13() {
    let Some(b) = require("bandai/dataset-1/dataset-1_walk_happy_001.bvh") else {
        return;
    };
    let Some(c) = require("cmu/01_01.bvh") else {
        return;
    };
    for p in [b, c] {
        let src = load(&p).motion;
        let map = JointMap::resolve(&src.skeleton, &BTreeMap::new()).unwrap();
        let out = retarget_to_smpl13(&src, &map).unwrap();
        assert_eq!(out.skeleton.kind, "smpl13");
        let err = bone_direction_error(&src, &out, &map).unwrap();
        assert!(err.to_degrees() < 0.01, "{}: {err} rad", p.display());
        let n = out.normalize_root().unwrap();
        let f = n.facing(0).unwrap();
        assert!((f[2] - 1.0).abs() < 1e-6);
        let pos = n.cut(0, 1).unwrap().positions();
        assert!(
            pos[3][1] < pos[1][1] && pos[4][1] < pos[2][1],
            "knees below hips"
        );
        assert!(pos[5][1] < pos[3][1], "ankle below knee");
    }
}

/// Same physical pose, same rotations: an AIST++ dance written as BVH with a
/// turned rest frame is retargeted back to (nearly) the SMPL-13 rotations.
#[test]
fn aist_through_bvh_retarget_recovers_smpl13_directions() {
    let Some(p) = require("aistpp/motions/gBR_sBM_cAll_d04_mBR2_ch08.pkl") else {
        return;
    };
    let m = load(&p).motion;
    let text = bvh::write_bvh(&m, &bvh::BvhWriteOptions::default()).unwrap();
    let b = bvh::read_bvh("x.bvh", &text, &bvh::BvhReadOptions::default())
        .unwrap()
        .motion;
    let map = JointMap::resolve(&b.skeleton, &BTreeMap::new()).unwrap();
    let out = retarget_to_smpl13(&b, &map).unwrap();
    let direct = m.to_smpl13().unwrap();
    // Pelvis orientation exactly; limbs up to twist about their own bone.
    for f in 0..m.frames() {
        assert!(geodesic_axis_angle(direct.rot(f, 0), out.rot(f, 0)) < 1e-6);
    }
    let err = bone_direction_error(&b, &out, &map).unwrap();
    assert!(err.to_degrees() < 0.01);
}

/// The split does not move with the spelling of the data folder, and the
/// bundled model's style exemplars all come from its training side: no
/// exemplar's source is a clip `eval generate` holds out as real
/// reference (session 17: the split hashed the path as typed, so
/// `/work/shared/data` and `../shared/data` held out different clips).
#[test]
fn the_split_ignores_the_path_spelling_and_exemplars_are_never_held_out() {
    use choreo::eval::generate::read_split;
    use choreo::lm::exemplars::Exemplars;
    use choreo::lm::frame::FrameManifest;
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    let (manifest, _, _) = FrameManifest::load(&model).unwrap();
    let vocab = manifest.vocabulary;
    let ex = Exemplars::load(&model, &vocab)
        .unwrap()
        .expect("bundled exemplars");
    let file = |n: &str| {
        Path::new(n)
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let sources: std::collections::BTreeSet<String> =
        ex.items.iter().map(|e| file(&e.source)).collect();
    for corpus in ["aistpp-vrm/motions", "bandai"] {
        let Some(dir) = require(corpus) else { return };
        let (held, train) = read_split(&vocab, &dir, 0.1, &mut |_| {}).unwrap();
        // The same folder spelled another way: absolute, with `.` parts.
        let other = std::fs::canonicalize(&dir).unwrap().join(".");
        let (held2, _) = read_split(&vocab, &other, 0.1, &mut |_| {}).unwrap();
        let names = |v: &[choreo::eval::generate::RealClip]| {
            v.iter().map(|c| file(&c.name)).collect::<Vec<_>>()
        };
        let mut a = names(&held);
        let mut b = names(&held2);
        a.sort();
        b.sort();
        assert!(!a.is_empty() && !train.is_empty(), "{corpus}");
        assert_eq!(a, b, "{corpus}: the held-out clips moved with the spelling");
        let leaked: Vec<&String> = a.iter().filter(|n| sources.contains(*n)).collect();
        assert!(
            leaked.is_empty(),
            "{corpus}: exemplars from held-out clips {leaked:?}"
        );
        let used = names(&train)
            .iter()
            .filter(|n| sources.contains(*n))
            .count();
        assert!(used > 0, "{corpus}: no exemplar from its training side");
    }
}

/// The root's path rebuilt from the feet (what `root: "feet"` does to a
/// generated clip) recovers a real walk's travel from its legs alone: the
/// Bandai takes retargeted to SMPL-13, tokenized and decoded as the model
/// sees them, their root's ground path thrown away.
#[test]
fn the_feet_recover_real_travel() {
    use choreo::motion::contact::lock_feet;
    use choreo::tokenize::vocab::Vocabulary;
    let Some(dir) = require("bandai/dataset-1") else {
        return;
    };
    let v = Vocabulary::new(Default::default());
    let path_len = |m: &Motion| -> f64 {
        m.trans
            .windows(2)
            .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][2] - w[0][2]).powi(2)).sqrt())
            .sum()
    };
    let end = |m: &Motion| -> [f64; 2] {
        let (a, b) = (m.trans[0], m.trans[m.frames() - 1]);
        [b[0] - a[0], b[2] - a[2]]
    };
    let mut report = Vec::new();
    for name in [
        "dataset-1_walk_happy_001",
        "dataset-1_walk_normal_001",
        "dataset-1_walk-back_normal_001",
        "dataset-1_run_normal_001",
        "dataset-1_bow_active_001",
    ] {
        let p = dir.join(format!("{name}.bvh"));
        let src = retargeted(&p);
        let tokens = v.encode_motion(&v.prepare(&src).unwrap()).unwrap();
        let real = v.decode_motion(&tokens, name).unwrap();
        let mut still = real.clone();
        for t in &mut still.trans {
            (t[0], t[2]) = (0.0, 0.0);
        }
        let feet = lock_feet(&still);
        let (lr, lf) = (path_len(&real), path_len(&feet));
        let (er, ef) = (end(&real), end(&feet));
        let miss = ((er[0] - ef[0]).powi(2) + (er[1] - ef[1]).powi(2)).sqrt();
        let dist = (er[0].powi(2) + er[1].powi(2)).sqrt();
        report.push(format!(
            "{name}: real path {lr:.2} m (ends {dist:.2} m away), feet path {lf:.2} m, ends {miss:.2} m apart"
        ));
        let all = report.join("\n");
        if name.contains("bow") {
            // Standing: no travel made up.
            assert!(lf < 0.75 && (ef[0].hypot(ef[1])) < 0.2, "{all}");
        } else if name.contains("run") {
            // A run's flight phases carry no foot: with the root's own path
            // thrown away, part of the travel is lost, but not its sense.
            let along = (er[0] * ef[0] + er[1] * ef[1]) / dist;
            assert!(along > 0.3 * dist && miss < dist, "{all}");
        } else {
            // A walk always has a foot down: the travel comes back within
            // 30 % (SMPL-13's legs are not the actor's).
            assert!((lf / lr - 1.0).abs() < 0.3, "{all}");
            assert!(miss < 0.3 * dist, "{all}");
        }
    }
    println!("{}", report.join("\n"));
}

/// Feet pinned where they touch the floor (what `feet: "pin"` does to a
/// generated clip), on real dance: AIST++-VRM dances have no root
/// trajectory, so a planted foot slides whenever the dancer travelled.
/// Pinned, the ankles slide less while slowly down (the contacts of
/// breaking footwork last 1–3 frames at 20 fps, so only part of it is
/// held), no ankle jumps, the rest of the body is unchanged, and a real
/// Bandai take that keeps its root (its feet do not slide) is left nearly
/// as it was.
#[test]
fn pinned_feet_stop_real_sliding_and_leave_real_steps_alone() {
    use choreo::motion::foot_pin::{pin_feet, PIN_SPEED};
    use choreo::tokenize::vocab::Vocabulary;
    let (Some(vrm), Some(bandai)) = (require("aistpp-vrm/motions"), require("bandai/dataset-1"))
    else {
        return;
    };
    let v = Vocabulary::new(Default::default());
    // Skating as the eval measures it (ankles' ground speed while within
    // 3 cm of the clip's lowest ankle height, m/s), over the frames where
    // the unpinned ankle also moves slower than the pin's speed limit (a
    // fast sweep along the floor is footwork, and is left alone).
    let skate = |m: &Motion, free: &Motion| -> f64 {
        let (p, q) = (m.positions(), free.positions());
        let j = m.joints();
        let (mut s, mut n) = (0.0, 0usize);
        for name in ["Left_Ankle", "Right_Ankle"] {
            let k = m.skeleton.index_of(name).unwrap();
            let floor = (0..m.frames())
                .map(|f| q[f * j + k][1])
                .fold(f64::INFINITY, f64::min);
            let speed = |p: &[Vec3], f: usize| {
                let (a, b) = (p[(f - 1) * j + k], p[f * j + k]);
                (b[0] - a[0]).hypot(b[2] - a[2]) * m.fps
            };
            for f in 1..m.frames() {
                if q[f * j + k][1] < floor + 0.03 && speed(&q, f) < PIN_SPEED {
                    s += speed(&p, f);
                    n += 1;
                }
            }
        }
        s / n.max(1) as f64
    };
    let legs = choreo::motion::foot_pin::LEG_JOINTS;
    let mut report = Vec::new();
    let mut files = files_with_ext(&vrm, &["pkl"]);
    files.sort();
    let (mut before, mut after) = (0.0, 0.0);
    for p in files.iter().take(6) {
        let src = load(p).motion;
        let tokens = v.encode_motion(&v.prepare(&src).unwrap()).unwrap();
        let mut m = v.decode_motion(&tokens, "vrm").unwrap();
        for t in &mut m.trans {
            (t[0], t[2]) = (0.0, 0.0);
        }
        let pinned = pin_feet(&m);
        let (b, a) = (skate(&m, &m), skate(&pinned, &m));
        report.push(format!("{}: skating {b:.3} -> {a:.3} m/s", p.display()));
        before += b;
        after += a;
        let j = m.joints();
        for f in 0..m.frames() {
            for k in 0..j {
                if !legs.contains(&m.skeleton.names[k].as_str()) {
                    assert_eq!(m.rotations[f * j + k], pinned.rotations[f * j + k]);
                }
            }
        }
        assert_eq!(m.trans, pinned.trans);
        // No ankle jumps: a frame's step at most 5 cm beyond the unpinned one's.
        let (p, q) = (m.positions(), pinned.positions());
        for name in ["Left_Ankle", "Right_Ankle"] {
            let k = m.skeleton.index_of(name).unwrap();
            for f in 1..m.frames() {
                let step = |x: &[Vec3]| norm(sub(x[f * j + k], x[(f - 1) * j + k]));
                assert!(
                    step(&q) <= step(&p) + 0.05,
                    "frame {f}: {name} steps {:.3} m pinned, {:.3} free; off by {:.3} then {:.3}; height {:.3} {:.3}",
                    step(&q),
                    step(&p),
                    norm(sub(q[(f - 1) * j + k], p[(f - 1) * j + k])),
                    norm(sub(q[f * j + k], p[f * j + k])),
                    p[(f - 1) * j + k][1],
                    p[f * j + k][1]
                );
            }
        }
    }
    let all = report.join("\n");
    assert!(after < 0.75 * before, "{all}");
    // Real steps with their root: the pin barely moves the ankles.
    for name in ["dataset-1_walk_normal_001", "dataset-1_run_normal_001"] {
        let src = retargeted(&bandai.join(format!("{name}.bvh")));
        let m = v
            .decode_motion(&v.encode_motion(&v.prepare(&src).unwrap()).unwrap(), name)
            .unwrap();
        let pinned = pin_feet(&m);
        let (p, q) = (m.positions(), pinned.positions());
        let j = m.joints();
        let k = m.skeleton.index_of("Left_Ankle").unwrap();
        let moved: Vec<f64> = (0..m.frames())
            .map(|f| norm(sub(p[f * j + k], q[f * j + k])))
            .collect();
        let mean = moved.iter().sum::<f64>() / moved.len() as f64;
        report.push(format!(
            "{name}: left ankle moved {mean:.3} m on average, {:.3} at most",
            moved.iter().fold(0.0f64, |a, &b| a.max(b))
        ));
        assert!(mean < 0.025, "{}", report.join("\n"));
    }
    println!("{}", report.join("\n"));
}
