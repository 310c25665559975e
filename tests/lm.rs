//! The trainer and the runtime together: export parity (tract against the
//! trainer's forward pass, whole and incremental), streaming against
//! one-shot, decoding generated tokens, and the bad-input paths.
#![cfg(feature = "train")]

use candle_core::Device;
use choreo::lm::manifest::DataInfo;
use choreo::lm::runtime::Kv;
use choreo::lm::{FrameDecoder, Generator, LmSession, ModelConfig, Objective, PosScheme, Sampling};
use choreo::motion::{Labels, Motion, Skeleton};
use choreo::tokenize::vocab::Vocabulary;
use choreo::train::model::{AdamW, Gpt};
use choreo::train::{data, export, parity};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

fn vocab() -> Vocabulary {
    let mut labels: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    labels.insert(
        "genre".into(),
        ["gBR", "gJS"].iter().map(|s| s.to_string()).collect(),
    );
    labels.insert(
        "style".into(),
        ["happy", "sad", "proud"]
            .iter()
            .map(|s| s.to_string())
            .collect(),
    );
    Vocabulary::new(labels)
}

fn config(v: &Vocabulary, positions: PosScheme, objective: Objective) -> ModelConfig {
    ModelConfig {
        vocab_size: v.size(),
        d_model: 32,
        n_layers: 2,
        n_heads: 4,
        d_ff: 64,
        max_frames: 4,
        frame_len: v.frame_len(),
        cond_kinds: vec!["genre".into(), "style".into()],
        classes: vec![(
            "style".into(),
            vec!["happy".into(), "proud".into(), "sad".into()],
        )],
        positions,
        objective,
        ln_eps: 1e-5,
    }
}

/// A hand-made SMPL clip: the left elbow swings as a sine, the root walks.
fn sine_motion(frames: usize, phase: f64) -> Motion {
    let sk = Skeleton::smpl24();
    let mut rots = vec![[0.0; 3]; frames * 24];
    let mut trans = Vec::new();
    for f in 0..frames {
        let t = f as f64 / 60.0;
        rots[f * 24 + 18] = [
            0.0,
            0.0,
            0.8 * (2.0 * std::f64::consts::PI * t + phase).sin(),
        ];
        rots[f * 24 + 1] = [0.3 * (t + phase).sin(), 0.1, 0.0];
        trans.push([0.5 * t, 0.9, 0.0]);
    }
    let mut labels = Labels::new();
    labels.insert("genre".into(), "gBR".into());
    labels.insert(
        "style".into(),
        if phase > 1.0 { "sad" } else { "happy" }.into(),
    );
    Motion::new(&format!("sine{phase}"), 60.0, sk, trans, rots, labels).unwrap()
}

/// A few optimisation steps so the weights are not the initial ones.
fn trained(cfg: ModelConfig, v: &Vocabulary) -> Gpt {
    let dev = Device::Cpu;
    let model = Gpt::new(cfg, 0.0, &dev).unwrap();
    let motions: Vec<(String, Motion)> = (0..4)
        .map(|i| ("synthetic".to_string(), sine_motion(120, i as f64 * 0.7)))
        .collect();
    let corpus = data::build(motions, v, 0.25, true, DataInfo::default()).unwrap();
    let cum = choreo::train::cumulative(&corpus, v.frame_len());
    let s = choreo::train::RunSettings {
        steps: 3,
        batch: 2,
        lr: 3e-3,
        min_lr_ratio: 0.1,
        warmup: 1,
        weight_decay: 0.1,
        dropout: 0.0,
        eval_every: 10,
        seed: 1,
        keep_label: 0.8,
        classify_fraction: 0.5,
        class_weight: 1.0,
        mask_rate: 0.15,
        max_seconds: 0.0,
        corpus_weights: Default::default(),
        balance: None,
        context_noise: 0.0,
        own_context: 0.0,
    };
    let mut opt = AdamW::new(s.lr, s.weight_decay);
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(3);
    for _ in 0..3 {
        choreo::train::train_step(&model, &mut opt, v, &corpus, &cum, &s, &mut rng, &dev).unwrap();
    }
    model
}

/// model.onnx + manifest.json in a fresh temporary folder.
fn export_to_temp(model: &Gpt, v: &Vocabulary) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    export::export(
        model,
        v,
        DataInfo::default(),
        BTreeMap::new(),
        serde_json::json!({}),
        dir.path(),
    )
    .unwrap();
    dir
}

#[test]
fn exported_graph_matches_the_trainer_whole_and_incremental() {
    let v = vocab();
    for (pos, obj) in [
        (PosScheme::FrameSlot, Objective::Causal),
        (PosScheme::Absolute, Objective::Causal),
        (PosScheme::FrameSlot, Objective::Masked),
    ] {
        let model = trained(config(&v, pos, obj), &v);
        let dir = export_to_temp(&model, &v);
        let r = parity::check(
            &model,
            &v,
            dir.path(),
            11,
            &choreo::lm::engine::Engine::tract(),
        )
        .unwrap();
        eprintln!("{pos:?} {obj:?}: {r}");
        assert!(r.whole < 1e-4, "{r}");
        assert!(r.classes < 1e-4, "{r}");
        if obj == Objective::Causal {
            // A masked model sees the future, so it has no incremental form.
            assert!(r.incremental < 1e-4, "{r}");
        }
    }
}

fn exported(pos: PosScheme) -> (tempfile::TempDir, Arc<LmSession>) {
    let v = vocab();
    let model = trained(config(&v, pos, Objective::Causal), &v);
    let dir = export_to_temp(&model, &v);
    let s = Arc::new(LmSession::load(dir.path()).unwrap());
    (dir, s)
}

#[test]
fn streaming_equals_one_shot_and_decodes_to_valid_motion() {
    let (_d, s) = exported(PosScheme::FrameSlot);
    let v = &s.manifest.vocabulary;
    let fl = v.frame_len();
    let mut labels = Labels::new();
    labels.insert("style".into(), "sad".into());
    let sampling = Sampling {
        temperature: 1.0,
        top_k: 50,
        top_p: 0.95,
        seed: 42,
        guidance: 1.0,
        keep_near: 0,
        max_jump: 0,
        posture: 0.0,
        context: 0,
        draws: 1,
        pace: 0.0,
        jerk: 0.0,
        ease: 0.0,
        matching: 0.0,
        travel: 1.0,
        skate: 0.0,
    };
    // 11 frames: the window (4) slides several times.
    let run = |n: usize| {
        let mut g = Generator::new(s.clone(), &labels, &[], sampling.clone()).unwrap();
        (0..n)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect::<Vec<u32>>()
    };
    let a = run(11);
    let b = run(11);
    assert_eq!(a, b, "the same seed gives the same frames");
    let m = v.decode_motion(&a, "generated").unwrap();
    assert_eq!(m.frames(), 11);
    assert!(m
        .rotations
        .iter()
        .flatten()
        .chain(m.trans.iter().flatten())
        .all(|x| x.is_finite()));
    // Frame by frame decoding gives the same motion as decoding the whole.
    let mut dec = FrameDecoder::new();
    for f in 0..11 {
        let (rot, tr) = dec.decode(v, &a[f * fl..(f + 1) * fl]).unwrap();
        assert_eq!(rot, m.frame_rotations(f).to_vec());
        assert_eq!(tr, m.trans[f]);
    }
    // It writes as BVH and reads back.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("gen.bvh");
    choreo::motion::io::write_path(&m, &p, &Default::default()).unwrap();
    let back = choreo::motion::io::read_path(&p, &Default::default()).unwrap();
    assert_eq!(back.motion.frames(), 11);
}

#[test]
fn a_joint_prompt_is_kept_in_the_output() {
    let (_d, s) = exported(PosScheme::Absolute);
    let v = &s.manifest.vocabulary;
    let prompt = v.encode_motion(&sine_motion(60, 0.3)).unwrap();
    let slots = choreo::lm::prompt_slots(v, &["pelvis".into(), "left_elbow".into()]).unwrap();
    let forced = choreo::lm::forced_frames(&prompt, &slots);
    let mut g = Generator::new(s.clone(), &Labels::new(), &[], Sampling::default()).unwrap();
    for (f, want) in forced.iter().enumerate().take(9) {
        let got = g.next_frame(want).unwrap();
        for (slot, w) in want.iter().enumerate() {
            if let Some(t) = w {
                assert_eq!(got[slot], *t, "frame {f} slot {slot}");
            }
        }
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let (dir, s) = exported(PosScheme::FrameSlot);
    // A label value the model never saw.
    let mut l = Labels::new();
    l.insert("genre".into(), "gZZ".into());
    let e = Generator::new(s.clone(), &l, &[], Sampling::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("labels") && e.contains("gZZ"), "{e}");
    // A label kind the model does not condition on.
    let mut l = Labels::new();
    l.insert("tempo".into(), "120".into());
    let e = Generator::new(s.clone(), &l, &[], Sampling::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("labels.tempo"), "{e}");
    // An unknown prompt joint.
    let e = choreo::lm::prompt_slots(&s.manifest.vocabulary, &["tail".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("prompt.joints") && e.contains("tail"), "{e}");
    // Out-of-range positions never reach the graph.
    let e = s
        .step(
            &[1],
            &[choreo::lm::Pos { a: 999, b: 0 }],
            Kv::empty(s.config()),
        )
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("positions"), "{e}");
    // A manifest that does not match its ONNX file.
    let onnx = dir.path().join("model.onnx");
    let mut bytes = std::fs::read(&onnx).unwrap();
    let n = bytes.len();
    bytes[n - 5] ^= 0xff;
    std::fs::write(&onnx, &bytes).unwrap();
    let e = LmSession::load(dir.path()).err().unwrap().to_string();
    assert!(e.contains("onnx_sha256"), "{e}");
    // A missing manifest.
    let e = LmSession::load(&dir.path().join("nowhere"))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("nowhere"), "{e}");
}

#[test]
fn corrupt_checkpoint_and_empty_corpus_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let e = choreo::train::load_checkpoint(dir.path(), &Device::Cpu)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("checkpoint.json"), "{e}");
    // A checkpoint whose weights are garbage.
    let v = vocab();
    let model = Gpt::new(
        config(&v, PosScheme::FrameSlot, Objective::Causal),
        0.0,
        &Device::Cpu,
    )
    .unwrap();
    let opt = AdamW::new(1e-3, 0.0);
    let state = choreo::train::CheckpointState {
        config: model.cfg.clone(),
        vocabulary: v.clone(),
        settings: serde_json::from_value(serde_json::json!({
            "steps": 1, "batch": 1, "lr": 0.001, "min_lr_ratio": 0.1, "warmup": 1, "weight_decay": 0.0,
            "dropout": 0.0, "eval_every": 1, "seed": 0, "keep_label": 1.0, "classify_fraction": 0.0,
            "class_weight": 1.0, "mask_rate": 0.15, "max_seconds": 0.0
        }))
        .unwrap(),
        step: 0,
        adam_step: 0,
        history: vec![],
        regime: "scratch".into(),
        parent: None,
        data: DataInfo::default(),
        metrics: BTreeMap::new(),
    };
    choreo::train::save_checkpoint(dir.path(), &model, &opt, &state).unwrap();
    assert!(choreo::train::load_checkpoint(dir.path(), &Device::Cpu).is_ok());
    std::fs::write(
        dir.path().join("checkpoint.safetensors"),
        b"not a checkpoint",
    )
    .unwrap();
    let e = choreo::train::load_checkpoint(dir.path(), &Device::Cpu)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("checkpoint.safetensors"), "{e}");
    // An empty corpus.
    let empty = tempfile::tempdir().unwrap();
    let e = data::read_motions(&[("x".into(), empty.path().to_path_buf())])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("empty corpus"), "{e}");
}

/// Export an in-betweener to a fresh folder and load it back in tract.
fn export_inbetweener(
    net: &choreo::train::inbetween::InbetweenNet,
) -> (tempfile::TempDir, choreo::lm::inbetween::Inbetweener) {
    let dir = tempfile::tempdir().unwrap();
    choreo::train::inbetween::export(
        net,
        DataInfo::default(),
        Default::default(),
        serde_json::json!({}),
        dir.path(),
    )
    .unwrap();
    let model = choreo::lm::inbetween::Inbetweener::load(dir.path()).unwrap();
    (dir, model)
}

/// An in-betweener's base travels in its manifest: a fresh model (its output
/// layer starts at zero, so its residual is zero) rebuilds exactly the
/// Catmull-Rom spline when its base is `catmull-rom`, exactly SLERP when it
/// is `slerp`, and a manifest written before the field existed reads as
/// SLERP. Training examples start from the same base.
#[test]
fn inbetweener_base_is_kept_and_used() {
    use choreo::keyframes::inbetween::{catmull_rom, slerp};
    use choreo::lm::inbetween::{Base, InbetweenConfig, Inbetweener};
    use choreo::train::inbetween as ib;
    use rand::SeedableRng;
    let m = sine_motion(100, 0.3);
    let keys = vec![0, 12, 24, 36, 48, 60, 72, 84, 99];
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    for (base, want) in [
        (Base::CatmullRom, catmull_rom(&m, &keys).unwrap()),
        (Base::Slerp, slerp(&m, &keys).unwrap()),
    ] {
        let cfg = InbetweenConfig {
            window: 16,
            d_model: 16,
            n_layers: 1,
            n_heads: 2,
            d_ff: 32,
            ln_eps: 1e-5,
            condition: None,
            base,
        };
        let net = ib::InbetweenNet::new(cfg.clone(), &Device::Cpu).unwrap();
        let (dir, model) = export_inbetweener(&net);
        assert_eq!(model.config().base, base);
        let r = model.rebuild(&m, &keys).unwrap();
        let gap = r
            .positions()
            .iter()
            .zip(want.positions().iter())
            .map(|(a, b)| (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
        assert!(gap < 1e-6, "{base:?}: {gap} m from the base");
        // A training example's target is the clip minus this base.
        let clip = ib::Clip {
            corpus: "synthetic".into(),
            name: "sine".into(),
            labels: m.labels.clone(),
            motion: m.clone(),
        };
        let ex = ib::example(&cfg, &clip, 12, &mut rng).unwrap();
        assert!(ex.target.iter().all(|v| v.is_finite()));
        if base == Base::Slerp {
            // Without "base" (a manifest from before the field) it reads as SLERP.
            let path = dir.path().join("manifest.json");
            let mut v: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
            v["config"].as_object_mut().unwrap().remove("base");
            std::fs::write(&path, v.to_string()).unwrap();
            assert_eq!(
                Inbetweener::load(dir.path()).unwrap().config().base,
                Base::Slerp
            );
        }
    }
}

/// The learned in-betweener: the export in tract matches candle, a rebuild
/// keeps the keyframes and gives finite poses, training lowers the loss
/// on a clip SLERP cannot rebuild, and a broken export is a clear error.
#[test]
fn inbetweener_export_parity_rebuild_and_bad_manifests() {
    use choreo::lm::inbetween::{InbetweenConfig, Inbetweener};
    use choreo::train::inbetween as ib;
    use rand::SeedableRng;
    let cfg = InbetweenConfig {
        window: 16,
        d_model: 16,
        n_layers: 2,
        n_heads: 2,
        d_ff: 32,
        ln_eps: 1e-5,
        condition: Some(("genre".into(), vec!["gBR".into(), "gJS".into()])),
        base: Default::default(),
    };
    let dev = Device::Cpu;
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let net = ib::InbetweenNet::new(cfg.clone(), &dev).unwrap();
    // Training on a sine clip with keyframes 12 frames apart: SLERP cuts
    // the arcs, the model must learn them back.
    let clip = ib::Clip {
        corpus: "synthetic".into(),
        name: "sine".into(),
        labels: sine_motion(120, 0.3).labels.clone(),
        motion: sine_motion(120, 0.3),
    };
    let clips = vec![clip];
    let fixed: Vec<ib::Example> = (0..8)
        .map(|_| ib::example(&cfg, &clips[0], 12, &mut rng).unwrap())
        .collect();
    // The FK weights: mean 1, the pelvis above the spine above an elbow,
    // leaves (feet, head, hands) at the floor, the root translation high.
    let w = ib::pose_weights(ib::LossWeights::Fk);
    let mean = w.iter().sum::<f32>() / w.len() as f32;
    assert!((mean - 1.0).abs() < 1e-4, "mean weight {mean}");
    let joint = |j: usize| w[j * 6];
    assert!(joint(0) > joint(3) && joint(3) > joint(18), "{w:?}");
    let floor = joint(10);
    assert!([11, 15, 22, 23].iter().all(|&j| joint(j) == floor), "{w:?}");
    assert!(floor > 0.0 && floor < joint(18), "{w:?}");
    assert!(w[24 * 6] > joint(0), "{w:?}");
    assert_eq!(
        ib::pose_weights(ib::LossWeights::Uniform),
        vec![1.0; w.len()]
    );
    let before = ib::loss(&net, &fixed, &w, &dev)
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    // Enough steps at a moderate rate that the outcome does not hang on
    // the threads' summation order (150 steps at 3e-3 once ended above
    // SLERP under load).
    let settings = ib::Settings {
        steps: 300,
        batch: 8,
        lr: 2e-3,
        warmup: 5,
        weight_decay: 0.0,
        spacing: (12, 12),
        seed: 0,
        max_seconds: None,
        corpus_share: None,
        loss_weights: ib::LossWeights::Fk,
    };
    ib::train(&net, &clips, &settings, &mut rng, &dev, &mut |_, _, _| {}).unwrap();
    let after = ib::loss(&net, &fixed, &w, &dev)
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!(after < 0.5 * before, "loss {before} → {after}");

    let (dir, model) = export_inbetweener(&net);
    let d = ib::parity(&net, &model, &mut rng).unwrap();
    assert!(d < 1e-4, "tract vs candle {d}");
    ib::jitter(&net, &mut rng).unwrap();
    let (_dir2, jittered) = export_inbetweener(&net);
    let d = ib::parity(&net, &jittered, &mut rng).unwrap();
    assert!(d < 1e-4, "tract vs candle after jitter {d}");

    // Rebuild: keyframes untouched, every pose finite, and closer to the
    // clip than SLERP on the clip it learned.
    let m = sine_motion(100, 0.3);
    let keys = vec![0, 12, 24, 36, 48, 60, 72, 84, 99];
    let r = model.rebuild(&m, &keys).unwrap();
    assert_eq!(r.frames(), 100);
    for &k in &keys {
        assert_eq!(r.frame_rotations(k), m.frame_rotations(k), "keyframe {k}");
    }
    assert!(r.rotations.iter().flatten().all(|v| v.is_finite()));
    let s = choreo::keyframes::inbetween::slerp(&m, &keys).unwrap();
    let p = m.positions();
    let (e_s, e_l) = (
        choreo::keyframes::metrics::mse(&p, &s.positions()),
        choreo::keyframes::metrics::mse(&p, &r.positions()),
    );
    eprintln!("rebuild: learned {e_l} vs slerp {e_s}");
    assert!(e_l < e_s, "learned {e_l} vs slerp {e_s}");

    // A wrong hash, a language model's manifest, a bad window.
    let mpath = dir.path().join("manifest.json");
    let text = std::fs::read_to_string(&mpath).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["onnx_sha256"] = "00".into();
    std::fs::write(&mpath, v.to_string()).unwrap();
    let e = Inbetweener::load(dir.path()).unwrap_err().to_string();
    assert!(
        e.contains("manifest.json") && e.contains("onnx_sha256"),
        "{e}"
    );
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["kind"] = "motion-lm".into();
    std::fs::write(&mpath, v.to_string()).unwrap();
    let e = Inbetweener::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("kind"), "{e}");
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["config"]["window"] = 7.into();
    std::fs::write(&mpath, v.to_string()).unwrap();
    let e = Inbetweener::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("config.window"), "{e}");
    // A 13-joint clip is refused with the reason.
    let small = m.to_smpl13().unwrap();
    let e = jittered
        .rebuild(&small, &[0, 50, 99])
        .unwrap_err()
        .to_string();
    assert!(e.contains("SMPL-24"), "{e}");
}
