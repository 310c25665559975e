//! The frame-level model: training lowers held-out bits/frame below the
//! previous-frame baseline on a clip with continuity, the two exported
//! graphs match the trainer, generation through the runtime gives valid
//! frames (stream = one-shot for one seed, forced prompt slots kept), the
//! baselines are right on a hand-made sequence, and a bad manifest is a
//! clear error.
#![cfg(feature = "train")]

use candle_core::Device;
use choreo::lm::frame::FrameConfig;
use choreo::lm::manifest::DataInfo;
use choreo::lm::model::MotionModel;
use choreo::lm::Sampling;
use choreo::motion::{Labels, Motion, Skeleton};
use choreo::tokenize::vocab::Vocabulary;
use choreo::train::data::{self, Sequence};
use choreo::train::frame::{self as fr, FrameData, FrameNet};
use choreo::train::model::AdamW;
use choreo::train::{baselines, frame_export, RunSettings};
use std::collections::{BTreeMap, BTreeSet};

mod common;

fn vocab() -> Vocabulary {
    common::style_vocab()
}

fn config(v: &Vocabulary) -> FrameConfig {
    common::small_frame_config(v, 24)
}

/// A clip with continuity: the elbow and hip swing as sines (60 fps).
fn sine_motion(frames: usize, phase: f64, style: &str) -> Motion {
    sine_motion_amp(frames, phase, style, 1.0)
}

/// [`sine_motion`] with the elbow's swing scaled by `amp`.
fn sine_motion_amp(frames: usize, phase: f64, style: &str, amp: f64) -> Motion {
    let sk = Skeleton::smpl24();
    let mut rots = vec![[0.0; 3]; frames * 24];
    let mut trans = Vec::new();
    for f in 0..frames {
        let t = f as f64 / 60.0;
        rots[f * 24 + 18] = [
            0.0,
            0.0,
            amp * 0.9 * (2.0 * std::f64::consts::PI * 0.7 * t + phase).sin(),
        ];
        rots[f * 24 + 1] = [0.4 * (1.3 * t + phase).sin(), 0.1, 0.0];
        rots[f * 24 + 16] = [0.0, 0.5 * (0.9 * t + 2.0 * phase).cos(), 0.0];
        trans.push([0.0, 0.9, 0.0]);
    }
    let mut labels = Labels::new();
    labels.insert("style".into(), style.into());
    Motion::new(format!("sine{phase}"), 60.0, sk, trans, rots, labels).unwrap()
}

fn settings(steps: usize) -> RunSettings {
    RunSettings {
        steps,
        batch: 4,
        lr: 3e-3,
        min_lr_ratio: 0.1,
        warmup: 2,
        weight_decay: 0.0,
        dropout: 0.0,
        eval_every: 1000,
        seed: 1,
        keep_label: 0.8,
        classify_fraction: 0.25,
        class_weight: 1.0,
        mask_rate: 0.0,
        max_seconds: 0.0,
        corpus_weights: Default::default(),
        balance: None,
        context_noise: 0.0,
        own_context: 0.0,
    }
}

fn corpus(v: &Vocabulary) -> data::Corpus {
    let motions: Vec<(String, Motion)> = (0..6)
        .map(|i| {
            let style = if i % 2 == 0 { "happy" } else { "sad" };
            (
                "synthetic".to_string(),
                sine_motion(600, i as f64 * 0.9, style),
            )
        })
        .collect();
    data::build(motions, v, 0.2, false, DataInfo::default()).unwrap()
}

/// `--chain-takes`: a corpus's training takes alike but for their take
/// number become one sequence (bridged), held-out takes stay single, so
/// validation is exactly `build`'s.
#[test]
fn alike_training_takes_chain_and_held_out_takes_stay_single() {
    let v = vocab();
    let motions = || -> Vec<(String, Motion)> {
        (0..8)
            .map(|i| {
                let style = if i % 2 == 0 { "happy" } else { "sad" };
                let mut m = sine_motion(120, i as f64 * 0.9, style);
                m.labels.insert("take".into(), format!("{i:03}"));
                ("synthetic".to_string(), m)
            })
            .collect()
    };
    let plain = data::build(motions(), &v, 0.25, false, DataInfo::default()).unwrap();
    let chain = ["synthetic".to_string()];
    let chained =
        data::build_chained(motions(), &v, 0.25, false, DataInfo::default(), &chain).unwrap();
    let names = |s: &[data::Sequence]| s.iter().map(|q| q.name.clone()).collect::<Vec<_>>();
    assert_eq!(plain.val.len(), 2);
    assert_eq!(names(&plain.val), names(&chained.val));
    assert_eq!(plain.train.len(), 6);
    // Six training takes of two styles: two chains, each one style's takes.
    assert_eq!(chained.train.len(), 2);
    let styles: Vec<_> = chained
        .train
        .iter()
        .map(|s| s.labels["style"].clone())
        .collect();
    assert!(styles.contains(&"happy".to_string()) && styles.contains(&"sad".to_string()));
    assert!(chained.train.iter().all(|s| s.name.contains("alike takes")));
    // A joined take enters somewhere in its first half, after a short
    // bridge: the chains keep at least the first takes whole and the
    // others' second halves, and add no more than a bridge a join.
    let fl = v.frame_len();
    let frames = |s: &[data::Sequence]| s.iter().map(|q| q.frames(fl)).sum::<usize>() as f64;
    let joins = (plain.train.len() - chained.train.len()) as f64;
    let (all, kept) = (frames(&plain.train), frames(&chained.train));
    let take = all / plain.train.len() as f64;
    let bridge = choreo::motion::Motion::CHAIN_BRIDGE_S * v.fps;
    assert!(
        kept <= all + joins * (bridge + 2.0) && kept >= all - joins * (take / 2.0 + 2.0),
        "{kept} frames chained of {all}, {joins} joins"
    );
    assert_eq!(chained.info.chained_takes, chain.to_vec());
    // A corpus not named is left alone.
    let other = ["bandai".to_string()];
    let same =
        data::build_chained(motions(), &v, 0.25, false, DataInfo::default(), &other).unwrap();
    assert_eq!(names(&same.train), names(&plain.train));
}

fn trained(v: &Vocabulary, c: &data::Corpus, steps: usize) -> FrameNet {
    let dev = Device::Cpu;
    let net = FrameNet::new(config(v), &dev).unwrap();
    let s = settings(steps);
    let d = FrameData::new(&c.train, v.frame_len());
    let mut opt = AdamW::new(s.lr, s.weight_decay);
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(5);
    for step in 0..steps {
        opt.lr = choreo::train::lr_at(&s, step);
        fr::train_step(
            &net,
            &mut opt,
            v,
            &d,
            net.cfg.max_frames,
            &s,
            &mut rng,
            &dev,
        )
        .unwrap();
    }
    net
}

fn export(net: &FrameNet, v: &Vocabulary) -> tempfile::TempDir {
    common::export_frame(net, v)
}

#[test]
fn training_beats_the_previous_frame_baseline_on_smooth_motion() {
    let v = vocab();
    let c = corpus(&v);
    let fl = v.frame_len();
    let before = FrameNet::new(config(&v), &Device::Cpu).unwrap();
    let b0 = fr::evaluate(&before, &v, &c.val, fl, usize::MAX, &Device::Cpu).unwrap();
    let net = trained(&v, &c, 150);
    let ev = fr::evaluate(&net, &v, &c.val, fl, usize::MAX, &Device::Cpu).unwrap();
    let delta = baselines::delta_loss(&c.train, &c.val, v.size(), v.bins, fl);
    let delta_bits = choreo::lm::bits_per_frame(delta, fl);
    eprintln!(
        "untrained {:.1}, trained {:.1}, delta baseline {:.1} bits/frame",
        b0.bits_per_frame, ev.bits_per_frame, delta_bits
    );
    assert!(ev.bits_per_frame < 0.5 * b0.bits_per_frame);
    // Sines have a steady velocity the model reads from the last two
    // frames: it must do clearly better than "same change as usual".
    assert!(
        ev.bits_per_frame < delta_bits,
        "{} vs {delta_bits}",
        ev.bits_per_frame
    );
}

#[test]
fn exported_graphs_match_the_trainer() {
    let v = vocab();
    let c = corpus(&v);
    let net = trained(&v, &c, 20);
    let dir = export(&net, &v);
    let values = fr::value_frames(&c.val[0].tokens, v.frame_len());
    let mut labels = Labels::new();
    labels.insert("style".into(), "sad".into());
    let (worst, scale) = frame_export::parity(
        &net,
        &v,
        dir.path(),
        &values,
        &labels,
        &choreo::lm::engine::Engine::tract(),
    )
    .unwrap();
    eprintln!("parity {worst:.2e} (logits up to {scale:.1})");
    assert!(scale > 0.1);
    assert!(worst < 1e-4, "{worst}");

    // `--init-from` an export: its vocabulary, and every trainer
    // parameter read back from the two graphs bit for bit, except the
    // class heads (fitted heads are not the trainer's).
    let (v2, t, _, _) = fr::init_source(dir.path(), &Device::Cpu).unwrap();
    assert_eq!(v2, v);
    let mut checked = 0;
    for (name, var) in net.params.0.iter() {
        if name.starts_with("cls.") {
            assert!(!t.contains_key(name), "{name} taken from the export");
            continue;
        }
        let got = t.get(name).unwrap_or_else(|| panic!("{name} missing"));
        let (a, b) = (
            var.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            got.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
        );
        assert_eq!(a, b, "{name}");
        checked += 1;
    }
    assert!(checked > 10, "{checked} parameters compared");
    let fresh = FrameNet::new(net.cfg.clone(), &Device::Cpu).unwrap();
    let missing = fresh.params.load_matching(&t, "export").unwrap();
    assert!(missing.iter().all(|n| n.starts_with("cls.")), "{missing:?}");
}

#[test]
fn generation_streams_the_same_frames_and_keeps_prompts() {
    let v = vocab();
    let c = corpus(&v);
    let net = trained(&v, &c, 20);
    let dir = export(&net, &v);
    let model = MotionModel::load(dir.path()).unwrap();
    assert_eq!(model.kind(), "motion-frame-lm");
    let fl = v.frame_len();
    let mut labels = Labels::new();
    labels.insert("style".into(), "happy".into());
    let sampling = Sampling {
        temperature: 1.0,
        top_k: 0,
        top_p: 0.95,
        seed: 9,
        guidance: 1.0,
        keep_near: 1,
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
    // More frames than the context: the window slides.
    let n = 2 * net.cfg.max_frames + 5;
    let run_with = |sampling: &Sampling, forced: &dyn Fn(usize) -> Vec<Option<u32>>| -> Vec<u32> {
        let mut g = model.generator(&labels, &[], sampling.clone()).unwrap();
        (0..n)
            .flat_map(|f| g.next_frame(&forced(f)).unwrap())
            .collect()
    };
    let run = |forced: &dyn Fn(usize) -> Vec<Option<u32>>| run_with(&sampling, forced);
    let free = |_f: usize| vec![None; fl];
    let a = run(&free);
    let b = run(&free);
    assert_eq!(a, b, "one seed, one stream");
    // sampling.context: a window of 4 frames gives the same frames until it
    // first slides (the 5th frame is still decoded from the state of frames
    // 1–4; the 5th is then fed onto 3–4 alone, so the 6th differs), then
    // its own clip, the same for one seed.
    let short = Sampling {
        context: 4,
        ..sampling.clone()
    };
    let s4 = run_with(&short, &free);
    assert_eq!(s4, run_with(&short, &free));
    assert_eq!(s4[..5 * fl], a[..5 * fl]);
    assert_ne!(s4, a);
    let whole = Sampling {
        context: net.cfg.max_frames as u32,
        ..sampling.clone()
    };
    assert_eq!(run_with(&whole, &free), a, "context = the window: as 0");
    // sampling.draws: several candidate frames, one kept; the same for one
    // seed, another clip than one draw; greedy makes one candidate.
    let four = Sampling {
        draws: 4,
        ..sampling.clone()
    };
    let d4 = run_with(&four, &free);
    assert_eq!(d4, run_with(&four, &free), "one seed, one stream");
    assert_ne!(d4, a);
    let greedy = Sampling::default();
    assert_eq!(
        run_with(
            &Sampling {
                draws: 4,
                ..greedy.clone()
            },
            &free
        ),
        run_with(&greedy, &free)
    );
    // sampling.pace holds the pace of the motion continued: with no seed
    // motion there is none to hold and the clip is the plain 4-draw one;
    // continuing one, it keeps other candidates (the same for one seed).
    let paced = Sampling {
        pace: 10.0,
        ..four.clone()
    };
    assert_eq!(run_with(&paced, &free), d4, "no seed, nothing to hold");
    let seed_motion = a[..8 * fl].to_vec();
    let go_on = |s: &Sampling| -> Vec<u32> {
        let mut g = model.generator(&labels, &seed_motion, s.clone()).unwrap();
        (0..n)
            .flat_map(|f| g.next_frame(&free(f)).unwrap())
            .collect()
    };
    let held = go_on(&paced);
    assert_eq!(held, go_on(&paced), "one seed, one stream");
    assert_ne!(held, go_on(&four), "the hold chooses other candidates");
    for (bad, says) in [
        (
            Sampling {
                pace: 10.0,
                ..sampling.clone()
            },
            "sampling.draws 2 or more",
        ),
        (
            Sampling {
                pace: 101.0,
                ..four.clone()
            },
            "0 to 100",
        ),
    ] {
        let e = model
            .generator(&labels, &seed_motion, bad)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("sampling.pace") && e.contains(says), "{e}");
    }
    for bad in [0, choreo::lm::sampling::MAX_DRAWS + 1] {
        let e = model
            .generator(
                &labels,
                &[],
                Sampling {
                    draws: bad,
                    ..sampling.clone()
                },
            )
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("sampling.draws") && e.contains("1 to 16"), "{e}");
    }
    for (bad, says) in [
        (1, "at least 2"),
        (net.cfg.max_frames as u32 + 1, "at most"),
    ] {
        let e = model
            .generator(
                &labels,
                &[],
                Sampling {
                    context: bad,
                    ..sampling.clone()
                },
            )
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("sampling.context") && e.contains(says), "{e}");
    }
    assert_eq!(a.len(), n * fl);
    for f in a.chunks_exact(fl) {
        assert_eq!(f[fl - 1], v.sep());
        assert!(f[..fl - 1].iter().all(|&t| (t as usize) < v.bins));
    }
    let m = v.decode_motion(&a, "generated").unwrap();
    assert_eq!(m.frames(), n);
    assert!(m.rotations.iter().flatten().all(|x| x.is_finite()));
    // A joint prompt's slots come out as given.
    let forced = |f: usize| {
        let mut x = vec![None; fl];
        x[9] = Some(100 + (f % 7) as u32);
        x
    };
    let p = run(&forced);
    for (f, fr) in p.chunks_exact(fl).enumerate() {
        assert_eq!(fr[9], 100 + (f % 7) as u32);
    }
    // With candidate frames too: every candidate keeps the forced slots.
    let p4 = run_with(&four, &forced);
    for (f, fr) in p4.chunks_exact(fl).enumerate() {
        assert_eq!(fr[9], 100 + (f % 7) as u32);
    }
    // max_jump: no slot moves further a frame (the shorter way round);
    // this barely trained model does without it.
    let biggest = |t: &[u32]| {
        let frames: Vec<&[u32]> = t.chunks_exact(fl).collect();
        frames
            .windows(2)
            .flat_map(|w| {
                (0..fl - 1).map(move |s| {
                    let d = (w[0][s] as i64 - w[1][s] as i64).abs();
                    d.min(v.bins as i64 - d)
                })
            })
            .max()
            .unwrap()
    };
    assert!(biggest(&a) > 3, "the unlimited draw moves {}", biggest(&a));
    for j in [1, 3] {
        let limited = run_with(
            &Sampling {
                max_jump: j,
                ..sampling.clone()
            },
            &free,
        );
        assert!(biggest(&limited) <= j as i64, "max_jump {j}");
        assert!(biggest(&limited) > 0, "max_jump {j}: still moves");
    }
    let e = Sampling {
        max_jump: 181,
        ..sampling.clone()
    }
    .validate()
    .unwrap_err()
    .to_string();
    assert!(e.contains("sampling.max_jump"), "{e}");
    // Classification reads the class head.
    let cls = model.classify(&a, 4).unwrap();
    assert_eq!(cls[0].0, "style");
    let total: f64 = cls[0].1.iter().map(|x| x.1).sum();
    assert!((total - 1.0).abs() < 1e-6);
}

#[test]
fn posture_pulls_the_joints_toward_the_labels_posture() {
    use choreo::lm::posture::{up_tilt_degrees, Postures, FILE};
    let v = vocab();
    let c = corpus(&v);
    let net = trained(&v, &c, 20);
    let dir = export(&net, &v);
    let fl = v.frame_len();
    let bins = v.bins as f64;
    let mut labels = Labels::new();
    labels.insert("style".into(), "happy".into());
    let plain_s = Sampling {
        temperature: 1.0,
        top_p: 0.95,
        seed: 3,
        keep_near: 1,
        ..Sampling::default()
    };
    let pulled_s = Sampling {
        posture: 2.0,
        ..plain_s.clone()
    };
    let n = 120;
    let gen = |m: &MotionModel, s: &Sampling| -> Vec<u32> {
        let mut g = m.generator(&labels, &[], s.clone()).unwrap();
        (0..n)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect()
    };
    // Without postures.json the pull is refused, naming the field.
    let model = MotionModel::load(dir.path()).unwrap();
    let e = model
        .generator(&labels, &[], pulled_s.clone())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("sampling.posture"), "{e}");
    let plain = gen(&model, &plain_s);
    // A slot's mean bin over the clip (the shorter way round for an angle).
    let slot_mean = |t: &[u32], s: usize, wraps: bool| -> f64 {
        let xs = t.chunks_exact(fl).map(|f| f[s] as f64);
        if wraps {
            let w = std::f64::consts::TAU / bins;
            let (a, b) = xs.fold((0.0, 0.0), |(a, b), x| {
                (a + (x * w).cos(), b + (x * w).sin())
            });
            b.atan2(a).rem_euclid(std::f64::consts::TAU) / w
        } else {
            xs.sum::<f64>() / n as f64
        }
    };
    let dist = |a: f64, b: f64, wraps: bool| {
        let d = (a - b).abs();
        if wraps {
            d.min(bins - d)
        } else {
            d
        }
    };
    // Postures fitted on a happy clip, each pulled slot's mean then set an
    // eighth of the range away from where the plain clip sits.
    let happy = sine_motion(600, 0.0, "happy");
    let toks = v.prepare(&happy).and_then(|p| v.encode_motion(&p)).unwrap();
    let mut p = Postures::fit(
        &[("happy".into(), happy.labels.clone(), toks.clone())],
        &v,
        &["style".into()],
        &Default::default(),
    );
    let nj = v.joints.len();
    let mut targets = Vec::new();
    for (s, st) in p
        .labels
        .get_mut("style")
        .unwrap()
        .get_mut("happy")
        .unwrap()
        .iter_mut()
        .enumerate()
    {
        if let Some(st) = st {
            let wraps = s < 3 * nj;
            let m = slot_mean(&plain, s, wraps);
            let t = if wraps {
                (m + bins / 8.0).rem_euclid(bins)
            } else if m < bins / 2.0 {
                m + bins / 8.0
            } else {
                m - bins / 8.0
            };
            st.mean = t;
            targets.push((s, t, wraps));
        }
    }
    assert!(!targets.is_empty());
    assert!(
        targets
            .iter()
            .all(|&(s, _, _)| s >= 3 && s != 3 * nj && s != 3 * nj + 1),
        "the root's rotation and ground velocity are not pulled"
    );
    std::fs::write(dir.path().join(FILE), serde_json::to_string(&p).unwrap()).unwrap();
    let model = MotionModel::load(dir.path()).unwrap();
    let pulled = gen(&model, &pulled_s);
    assert_eq!(pulled, gen(&model, &pulled_s), "one seed, one clip");
    assert_eq!(
        plain,
        gen(&model, &plain_s),
        "posture 0 leaves the draw as it was"
    );
    // sampling.ease loosens the pull while the clip is slower than the
    // motion it continues: a still seed is never faster than the clip, so
    // the pull stays whole and the clip is the uneased one; a moving seed
    // eases it (other frames, the same for one seed); with no seed there
    // is nothing to ease against. Without a pull, or past 10, refused.
    let eased_s = Sampling {
        ease: 2.0,
        ..pulled_s.clone()
    };
    assert_eq!(
        gen(&model, &eased_s),
        pulled,
        "no seed, nothing to ease against"
    );
    let go_on = |seed: &[u32], s: &Sampling| -> Vec<u32> {
        let mut g = model.generator(&labels, seed, s.clone()).unwrap();
        (0..n)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect()
    };
    let still: Vec<u32> = (0..12).flat_map(|_| toks[..fl].to_vec()).collect();
    assert_eq!(
        go_on(&still, &eased_s),
        go_on(&still, &pulled_s),
        "a still seed"
    );
    let moving = &toks[..12 * fl];
    let eased = go_on(moving, &eased_s);
    assert_eq!(eased, go_on(moving, &eased_s), "one seed, one clip");
    assert_ne!(
        eased,
        go_on(moving, &pulled_s),
        "a moving seed eases the pull"
    );
    for (bad, says) in [
        (
            Sampling {
                ease: 1.0,
                ..plain_s.clone()
            },
            "sampling.posture is 0",
        ),
        (
            Sampling {
                ease: 11.0,
                ..pulled_s.clone()
            },
            "0 to 10",
        ),
    ] {
        let e = model
            .generator(&labels, moving, bad)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("sampling.ease") && e.contains(says), "{e}");
    }
    // sampling.matching: the joints follow the labels' real takes. Without
    // exemplars.json, without labels, or past 10: refused, naming it.
    let matching_s = Sampling {
        matching: 3.0,
        ..pulled_s.clone()
    };
    let refused = |m: &MotionModel, l: &Labels, s: &Sampling, says: &str| {
        let e = m.generator(l, moving, s.clone()).err().unwrap().to_string();
        assert!(e.contains("sampling.matching") && e.contains(says), "{e}");
    };
    refused(&model, &labels, &matching_s, "no exemplars.json");
    let ex = choreo::lm::exemplars::Exemplars::build(
        &[("happy".into(), happy.labels.clone(), toks.clone())],
        &v,
        &["style".to_string()],
        5.0,
        1,
        None,
        choreo::lm::exemplars::SpanChoice::default(),
    )
    .unwrap();
    ex.save(dir.path()).unwrap();
    let model = MotionModel::load(dir.path()).unwrap();
    refused(&model, &Labels::new(), &matching_s, "asks for none");
    let mut sad = Labels::new();
    sad.insert("style".into(), "sad".into());
    refused(&model, &sad, &matching_s, "no exemplar span");
    // A matching the request did not name (a kind's default) applies only
    // where there are takes to follow: dropped for "sad", not refused;
    // named, it stays (and is refused above).
    assert!(model.can_match(&labels) && !model.can_match(&sad));
    assert!(!model.can_match(&Labels::new()));
    let filled = |l: &Labels, matching: bool| {
        let mut s = matching_s.clone();
        let named = choreo::lm::model::Named {
            matching,
            ..Default::default()
        };
        model.fill_defaults(l, &mut s, named);
        s.matching
    };
    assert_eq!(
        (
            filled(&labels, false),
            filled(&sad, false),
            filled(&sad, true)
        ),
        (3.0, 0.0, 3.0)
    );
    refused(
        &model,
        &labels,
        &Sampling {
            matching: 11.0,
            ..matching_s.clone()
        },
        "0 to 10",
    );
    let go_on = |seed: &[u32], s: &Sampling| -> Vec<u32> {
        let mut g = model.generator(&labels, seed, s.clone()).unwrap();
        (0..n)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect()
    };
    let matched = go_on(moving, &matching_s);
    assert_eq!(matched, go_on(moving, &matching_s), "one seed, one clip");
    // sampling.travel past 10: refused, naming it.
    let e = model
        .generator(
            &labels,
            moving,
            Sampling {
                travel: 11.0,
                ..matching_s.clone()
            },
        )
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("sampling.travel") && e.contains("0 to 10"),
        "{e}"
    );
    // Its frames lie nearer the library's real frames (joint angles and
    // the root's height) than the pulled clip's do.
    let library: Vec<Vec<u32>> = ex
        .spans()
        .flat_map(|(_, t)| t.chunks_exact(fl).map(|f| f.to_vec()).collect::<Vec<_>>())
        .collect();
    let slots = fl - 1;
    let off_library = |clip: &[u32]| -> f64 {
        let frames: Vec<&[u32]> = clip.chunks_exact(fl).collect();
        let near = |f: &[u32]| -> f64 {
            library
                .iter()
                .map(|x| {
                    (0..slots)
                        .filter(|&s| choreo::lm::matching::followed(s, slots))
                        .map(|s| {
                            let d = (f[s] as f64 - x[s] as f64).abs();
                            let d = if s + 1 < slots { d.min(bins - d) } else { d };
                            d * d
                        })
                        .sum::<f64>()
                })
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        };
        frames.iter().map(|f| near(f)).sum::<f64>() / frames.len() as f64
    };
    let (followed, pulled_only) = (
        off_library(&matched),
        off_library(&go_on(moving, &pulled_s)),
    );
    assert!(
        followed < pulled_only,
        "matched clip {followed:.1} bins from the library, pulled {pulled_only:.1}"
    );
    let closer = targets
        .iter()
        .filter(|&&(s, t, w)| {
            dist(slot_mean(&pulled, s, w), t, w) < dist(slot_mean(&plain, s, w), t, w)
        })
        .count();
    assert!(
        closer * 10 >= targets.len() * 9,
        "{closer} of {} slots moved toward the labels' posture",
        targets.len()
    );
    // The root's tilt: the fitted figure is the training clip's own (from
    // its tokens), and a tilt asked 30° away from where the plain clip
    // stands moves the body toward it.
    let tilt_of = |t: &[u32]| -> f64 {
        let w = std::f64::consts::TAU / bins;
        let ts: Vec<f64> = t
            .chunks_exact(fl)
            .map(|f| {
                up_tilt_degrees([0, 1, 2].map(|i| -std::f64::consts::PI + (f[i] as f64 + 0.5) * w))
            })
            .collect();
        ts.iter().sum::<f64>() / ts.len() as f64
    };
    let fitted = p.tilt["style"]["happy"].clone();
    let own = tilt_of(&v.prepare(&happy).and_then(|q| v.encode_motion(&q)).unwrap());
    assert!((fitted.mean - own).abs() < 1e-9, "{fitted:?} vs {own}");
    let stand = tilt_of(&pulled);
    let mut tilted = p.clone();
    let want = (stand + 30.0).min(150.0);
    let st = tilted
        .tilt
        .get_mut("style")
        .unwrap()
        .get_mut("happy")
        .unwrap();
    st.mean = want;
    st.spread = 5.0;
    std::fs::write(
        dir.path().join(FILE),
        serde_json::to_string(&tilted).unwrap(),
    )
    .unwrap();
    let leaned = tilt_of(&gen(&MotionModel::load(dir.path()).unwrap(), &pulled_s));
    assert!(
        (leaned - want).abs() * 2.0 < (stand - want).abs(),
        "asked {want:.1}°: {leaned:.1}° (from {stand:.1}°)"
    );
    // A postures file that does not fit the model is a load error naming the field.
    let mut bad = p.clone();
    bad.tilt
        .get_mut("style")
        .unwrap()
        .get_mut("happy")
        .unwrap()
        .mean = 200.0;
    std::fs::write(dir.path().join(FILE), serde_json::to_string(&bad).unwrap()).unwrap();
    let e = MotionModel::load(dir.path()).err().unwrap().to_string();
    assert!(e.contains("tilt.style.happy"), "{e}");
    let mut bad = p.clone();
    bad.bins += 1;
    std::fs::write(dir.path().join(FILE), serde_json::to_string(&bad).unwrap()).unwrap();
    let e = MotionModel::load(dir.path()).err().unwrap().to_string();
    assert!(e.contains("postures.json") && e.contains("bins"), "{e}");
    let mut bad = p.clone();
    let happy_stats = bad.labels["style"]["happy"].clone();
    bad.labels
        .get_mut("style")
        .unwrap()
        .insert("angry".into(), happy_stats);
    std::fs::write(dir.path().join(FILE), serde_json::to_string(&bad).unwrap()).unwrap();
    let e = MotionModel::load(dir.path()).err().unwrap().to_string();
    assert!(e.contains("labels.style.angry"), "{e}");
    // Pose clusters: a cluster with no share, or with the wrong number of
    // slots, is named too.
    let good = choreo::lm::posture::Component {
        weight: 1.0,
        slots: p.labels["style"]["happy"].clone(),
    };
    for (weight, drop_slot, want) in [
        (0.0, false, "components.style.happy[0]"),
        (1.0, true, "components.style.happy[0]"),
    ] {
        let mut c = good.clone();
        c.weight = weight;
        if drop_slot {
            c.slots.pop();
        }
        let mut bad = p.clone();
        bad.components.insert(
            "style".into(),
            [("happy".to_string(), vec![c])].into_iter().collect(),
        );
        std::fs::write(dir.path().join(FILE), serde_json::to_string(&bad).unwrap()).unwrap();
        let e = MotionModel::load(dir.path()).err().unwrap().to_string();
        assert!(e.contains(want), "{e}");
    }
    // A good cluster loads.
    let mut ok = p.clone();
    ok.components.insert(
        "style".into(),
        [("happy".to_string(), vec![good])].into_iter().collect(),
    );
    std::fs::write(dir.path().join(FILE), serde_json::to_string(&ok).unwrap()).unwrap();
    MotionModel::load(dir.path()).unwrap();
}

#[test]
fn bad_frame_manifests_are_clear_errors() {
    let v = vocab();
    let net = FrameNet::new(config(&v), &Device::Cpu).unwrap();
    let dir = export(&net, &v);
    let mf = dir.path().join("manifest.json");
    let text = std::fs::read_to_string(&mf).unwrap();
    std::fs::write(&mf, text.replace("motion-frame-lm", "motion-vq")).unwrap();
    let e = MotionModel::load(dir.path()).err().unwrap().to_string();
    assert!(e.contains("kind") && e.contains("motion-vq"), "{e}");
    std::fs::write(&mf, &text).unwrap();
    std::fs::write(dir.path().join("local.onnx"), b"junk").unwrap();
    let e = MotionModel::load(dir.path()).err().unwrap().to_string();
    assert!(
        e.contains("local.onnx") || e.contains("local_sha256"),
        "{e}"
    );
    // Per-kind max_jump defaults: a kind the vocabulary lacks and a cap out
    // of range are start-up errors naming the field; the smallest listed
    // cap of a request's kinds applies, the recommended one without any.
    std::fs::write(&mf, &text).unwrap();
    let dir3 = export(&net, &v);
    let mf3 = dir3.path().join("manifest.json");
    let with = |extra: serde_json::Value| {
        let mut j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&mf3).unwrap()).unwrap();
        j["max_jump_by_kind"] = extra;
        std::fs::write(&mf3, j.to_string()).unwrap();
        MotionModel::load(dir3.path())
    };
    let kinds: Vec<String> = v.labels.keys().cloned().collect();
    for bad in [
        serde_json::json!({"tempo": 24}),
        serde_json::json!({kinds[0].clone(): 0}),
        serde_json::json!({kinds[0].clone(): 181}),
    ] {
        let e = with(bad.clone()).err().unwrap().to_string();
        assert!(e.contains("max_jump_by_kind"), "{bad}: {e}");
    }
    let m3 = with(serde_json::json!({kinds[0].clone(): 24})).unwrap();
    let other = "genre".to_string();
    assert_eq!(m3.default_max_jump([&kinds[0]]), 24);
    assert_eq!(m3.default_max_jump([&other, &kinds[0]]), 24);
    let recommended = choreo::lm::sampling::RECOMMENDED.max_jump;
    assert_eq!(m3.default_max_jump([&other]), recommended);
    assert_eq!(m3.default_max_jump(&Vec::<String>::new()), recommended);
    // Per-kind top_p and posture defaults: an unknown kind, a top_p or a
    // posture out of range, or a posture without postures.json are
    // start-up errors naming the field; the first listed kind's apply.
    let with_s = |extra: serde_json::Value| {
        let mut j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&mf3).unwrap()).unwrap();
        j["max_jump_by_kind"] = serde_json::json!({});
        j["sampling_by_kind"] = extra;
        std::fs::write(&mf3, j.to_string()).unwrap();
        MotionModel::load(dir3.path())
    };
    for (bad, field) in [
        (
            serde_json::json!({"tempo": {"top_p": 1.0}}),
            "sampling_by_kind.tempo".to_string(),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"top_p": 1.5}}),
            format!("sampling_by_kind.{}.top_p", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"posture": 11.0}}),
            format!("sampling_by_kind.{}.posture", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"posture": 2.0}}),
            format!("sampling_by_kind.{}.posture", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"draws": 0}}),
            format!("sampling_by_kind.{}.draws", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"draws": 17}}),
            format!("sampling_by_kind.{}.draws", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"pace": 101.0}}),
            format!("sampling_by_kind.{}.pace", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"jerk": -1.0}}),
            format!("sampling_by_kind.{}.jerk", kinds[0]),
        ),
        (
            serde_json::json!({kinds[0].clone(): {"temp": 2.0}}),
            "temp".to_string(),
        ),
    ] {
        let e = with_s(bad.clone()).err().unwrap().to_string();
        assert!(e.contains(&field), "{bad}: {e}");
    }
    let m4 = with_s(serde_json::json!({kinds[0].clone(): {"top_p": 0.8, "draws": 3}})).unwrap();
    let d = m4.kind_sampling([&other, &kinds[0]]);
    assert_eq!((d.top_p, d.posture, d.draws), (Some(0.8), None, Some(3)));
    // A request naming no draws gets the kind's; one naming it keeps its own.
    let mut s = choreo::lm::sampling::RECOMMENDED;
    m4.fill_kind_defaults([&kinds[0]], &mut s, Default::default());
    assert_eq!(s.draws, 3);
    let mut s = choreo::lm::sampling::RECOMMENDED;
    let named = choreo::lm::model::Named {
        draws: true,
        ..Default::default()
    };
    m4.fill_kind_defaults([&kinds[0]], &mut s, named);
    assert_eq!(s.draws, 1);
    assert_eq!(m4.kind_sampling([&other]), Default::default());
    // A kind's pace hold and jerk price come with its draws; a request that
    // names one draw gets neither (nothing to choose among), one naming
    // the field keeps its own.
    let m5 = with_s(serde_json::json!({kinds[0].clone(): {"draws": 4, "pace": 5.0, "jerk": 1.0}}))
        .unwrap();
    let prices = |named: choreo::lm::model::Named| {
        let mut s = choreo::lm::sampling::RECOMMENDED;
        m5.fill_kind_defaults([&kinds[0]], &mut s, named);
        (s.draws, s.pace, s.jerk)
    };
    assert_eq!(prices(Default::default()), (4, 5.0, 1.0));
    assert_eq!(prices(named), (1, 0.0, 0.0));
    let named_pace = choreo::lm::model::Named {
        pace: true,
        ..Default::default()
    };
    assert_eq!(prices(named_pace), (4, 0.0, 1.0));
    let named_jerk = choreo::lm::model::Named {
        jerk: true,
        ..Default::default()
    };
    assert_eq!(prices(named_jerk), (4, 5.0, 0.0));
    let mut labels = Labels::new();
    labels.insert("style".into(), "furious".into());
    let dir2 = export(&net, &v);
    let model = MotionModel::load(dir2.path()).unwrap();
    let e = model
        .generator(&labels, &[], Sampling::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("furious"), "{e}");
    let mut g = model
        .generator(&Labels::new(), &[], Sampling::default())
        .unwrap();
    let mut bad = vec![None; v.frame_len()];
    bad[3] = Some(v.sep());
    let e = g.next_frame(&bad).err().unwrap().to_string();
    assert!(e.contains("prompt slot 3"), "{e}");
}

#[test]
fn context_noise_moves_what_the_network_reads_not_what_it_is_scored_on() {
    use rand::SeedableRng;
    let v = vocab();
    let cfg = config(&v);
    let s = cfg.slots;
    let bins = cfg.bins as u32;
    // 6 frames; the first angle slot sits at the wrap (bin 0), the last
    // root slot at the top bin, the rest mid-range and moving.
    let values: Vec<u32> = (0..6)
        .flat_map(|f| {
            (0..s).map(move |k| match k {
                0 => 0,
                k if k == s - 1 => bins - 1,
                k => 100 + f as u32 * 2 + k as u32,
            })
        })
        .collect();
    let labels = Labels::new();
    let make = |seed: u64, noise: f64| {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        // From frame 2: two frames of history.
        let mut ex = fr::example(&cfg, &v, &values, 2, 4, &labels, false, 1.0, &mut rng);
        fr::add_context_noise(&cfg, &mut ex, noise, &mut rng);
        ex
    };
    // Off: nothing changes, and the batch is the clean one.
    let clean = make(7, 0.0);
    assert!(clean.context.is_none());
    let u = |t: &candle_core::Tensor| t.flatten_all().unwrap().to_vec1::<u32>().unwrap();
    let bc = fr::batch(&cfg, std::slice::from_ref(&clean), &Device::Cpu).unwrap();
    assert_eq!(u(&bc.val), clean.frames);
    // On: the frames read move, within bounds; the targets do not.
    let mut moved = 0;
    for seed in 0..20 {
        let ex = make(seed, 3.0);
        let (seen, hist) = ex.context.as_ref().expect("noisy context");
        assert_eq!(seen.len(), ex.frames.len());
        assert_eq!(hist.len(), 2);
        for (i, (&a, &b)) in ex.frames.iter().zip(seen).enumerate() {
            assert!(b < bins, "slot {i}: bin {b}");
            let d = (a as i64 - b as i64).abs();
            let d = if cfg.wraps(i % s) {
                d.min(bins as i64 - d)
            } else {
                d
            };
            assert!(d <= 18, "slot {i}: moved {d} bins at most σ 3");
            moved += usize::from(d > 0);
        }
        let b = fr::batch(&cfg, std::slice::from_ref(&ex), &Device::Cpu).unwrap();
        assert_eq!(&u(&b.val), seen, "the global input is the noisy frames");
        let (rel_t, prev) = (u(&b.rel_t), u(&b.prev));
        for f in 0..4 {
            let p1: &[u32] = if f == 0 {
                &hist[0]
            } else {
                &seen[(f - 1) * s..f * s]
            };
            for k in 0..s {
                let i = f * s + k;
                assert_eq!(
                    prev[i], p1[k],
                    "the local decoder reads the noisy previous frame"
                );
                assert_eq!(
                    rel_t[i],
                    cfg.change(Some(p1[k]), ex.frames[i]),
                    "the target is the true frame against what was read"
                );
            }
        }
    }
    assert!(moved > 20 * 4 * s / 4, "noise moved only {moved} slots");
}

#[test]
fn own_samples_replace_context_frames_within_the_change_window() {
    use rand::SeedableRng;
    let v = vocab();
    let cfg = config(&v);
    let s = cfg.slots;
    let net = FrameNet::new(cfg.clone(), &Device::Cpu).unwrap();
    let values: Vec<u32> = (0..8)
        .flat_map(|f| (0..s).map(move |k| 150 + (f * 3 + k) as u32 % 40))
        .collect();
    let labels = Labels::new();
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let mut exs: Vec<_> = [0, 2]
        .iter()
        .map(|&start| fr::example(&cfg, &v, &values, start, 6, &labels, false, 1.0, &mut rng))
        .collect();
    fr::add_own_samples(&net, &mut exs, 0.0, &mut rng, &Device::Cpu).unwrap();
    assert!(
        exs.iter().all(|e| e.context.is_none()),
        "share 0 changes nothing"
    );
    fr::add_own_samples(&net, &mut exs, 1.0, &mut rng, &Device::Cpu).unwrap();
    let mut changed = 0;
    for e in &exs {
        let (seen, hist) = e.context.as_ref().expect("own samples read");
        assert_eq!(hist, &e.hist, "the history before the window stays");
        for f in 0..6 {
            let p1: Option<&[u32]> = if f == 0 {
                e.hist.first().map(|p| p.as_slice())
            } else {
                Some(&e.frames[(f - 1) * s..f * s])
            };
            for k in 0..s {
                let (got, truth) = (seen[f * s + k], e.frames[f * s + k]);
                match p1 {
                    // A window's first frame without history is never replaced.
                    None => assert_eq!(got, truth),
                    Some(p) => {
                        let d = (got as i64 - p[k] as i64).abs();
                        let d = if cfg.wraps(k) {
                            d.min(cfg.bins as i64 - d)
                        } else {
                            d
                        };
                        assert!(
                            d <= cfg.radius as i64 || got == truth,
                            "frame {f} slot {k}: a draw {d} bins from the frame before"
                        );
                        changed += usize::from(got != truth);
                    }
                }
            }
        }
    }
    assert!(
        changed > 6 * s,
        "an untrained model's draws moved only {changed} slots"
    );
    let b = fr::batch(&cfg, &exs, &Device::Cpu).unwrap();
    let rel_t = b.rel_t.to_vec1::<u32>().unwrap();
    let (seen, _) = exs[1].context.as_ref().unwrap();
    let t = b.t;
    for k in 0..s {
        let i = (t + 3) * s + k;
        assert_eq!(
            rel_t[i],
            cfg.change(Some(seen[2 * s + k]), exs[1].frames[3 * s + k])
        );
    }
}

#[test]
fn delta_baseline_is_exact_on_a_hand_made_sequence() {
    // One slot plus the separator, 4 bins: training changes +1, +1, +1
    // (counts 1 + 3 on change +1 of 7 possible, add-one).
    let fl = 2;
    let seq = |toks: Vec<u32>| Sequence {
        name: "s".into(),
        corpus: "c".into(),
        labels: Labels::new(),
        tokens: toks,
        mirrored: None,
    };
    let sep = 4;
    let train = vec![seq(vec![0, sep, 1, sep, 2, sep, 3, sep])];
    let val = vec![seq(vec![1, sep, 2, sep])];
    let vocab_size = 8;
    let loss = baselines::delta_loss(&train, &val, vocab_size, 4, fl);
    // Frame 0 (slot unigram): value 1 seen once of 4 + 8 (add-one over 8 ids).
    let first = -(2.0f64 / 12.0).ln();
    // Separators: 4 of 4 + 8.
    let sep_cost = -(5.0f64 / 12.0).ln();
    // Frame 1: change +1 (count 4) over the changes reachable from bin 1
    // (−1, 0, +1, +2: counts 1, 1, 4, 1).
    let second = -(4.0f64 / 7.0).ln();
    let want = (first + sep_cost + second + sep_cost) / 4.0;
    assert!((loss - want).abs() < 1e-12, "{loss} vs {want}");
}

#[test]
fn eval_generate_reports_every_metric_on_real_held_out_clips() {
    use choreo::eval::generate::{eval_generate, GenOptions};
    let Some(dir) = choreo::data::require("aistpp-vrm/motions") else {
        return;
    };
    // A vocabulary that knows the AIST++ genres; an untrained frame model
    // is enough to check the table's shape and its real-data yardsticks.
    let genres = ["BR", "HO", "JB", "JS", "KR", "LH", "LO", "MH", "PO", "WA"];
    let mut labels: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    labels.insert(
        "genre".into(),
        genres.iter().map(|s| s.to_string()).collect(),
    );
    let v = Vocabulary::new(labels);
    let mut cfg = config(&v);
    cfg.cond_kinds = vec!["genre".into()];
    cfg.classes = vec![];
    let net = FrameNet::new(cfg, &Device::Cpu).unwrap();
    let out = export(&net, &v);
    let model = MotionModel::load(out.path()).unwrap();
    let o = GenOptions {
        label_kind: "genre".into(),
        per_label: 1,
        seconds: 2.0,
        held_out_lengths: false,
        samplings: vec![Sampling::default(), Sampling::recommended(1)],
        val_fraction: 0.1,
        exemplars: None,
        exemplar_modes: vec![false],
        candidates: vec![1],
        rank_every: 0,
        // The AIST++-VRM clips dance in place: both rows drop the ground
        // path (nothing real to compare travel with); the feet's row sets
        // the height from the feet.
        root_from_feet: vec![false, true],
        pin_feet: vec![false],
    };
    let mut said = Vec::new();
    let rows = eval_generate(&model, &dir, &o, &mut |l| said.push(l)).unwrap();
    assert_eq!(rows.len(), 4);
    for r in &rows {
        assert!(r.labels >= 2 && r.clips == r.labels, "{r:?}");
        assert!(
            r.fid_k_real.is_some_and(|x| x.is_finite() && x >= 0.0),
            "{r:?}"
        );
        // The same-size real yardstick: as many real training segments
        // as generated clips (here about ten), so FID's small-set bias
        // makes it larger than the yardstick over every training segment.
        let (same, all) = (r.fid_k_real_same_n.unwrap(), r.fid_k_real.unwrap());
        assert!(same.is_finite() && same > all, "{r:?}");
        // The features behind FID_k are named, each a real SMPL-24 joint
        // and one of its three measures, worst first.
        assert_eq!(r.fid_k_gaps.len(), 5, "{r:?}");
        assert!(r.fid_k_gaps.iter().all(|g| g.spread >= 0.0
            && g.z.is_finite()
            && ["horizontal speed²", "vertical speed²", "acceleration"]
                .iter()
                .any(|m| g.feature.ends_with(m))));
        assert!(r.fid_k_gaps.windows(2).all(|w| w[0].cost >= w[1].cost));
        assert!(r.fid_k_gaps.iter().all(|g| g.cost >= g.z * g.z - 1e-12));
        // FID_k along the real clips' first principal axis, and without
        // it: the axis's term and the rest are each at most FID_k's
        // order (they add up to it only where the axis is also the
        // generated set's), and the yardstick without it is finite.
        let ax = r.fid_k_axis.as_ref().unwrap();
        let fk = r.fid_k.unwrap();
        assert!(ax.real_share > 0.0 && ax.real_share <= 1.0, "{ax:?}");
        assert!(ax.real_var > 0.0 && ax.gen_var >= 0.0 && ax.shift.is_finite());
        assert!(ax.cost >= 0.0 && ax.fid_k_without >= 0.0 && ax.fid_k_without <= fk + 1e-9);
        assert!(
            ax.fid_k_real_same_n_without.is_some_and(f64::is_finite),
            "{ax:?}"
        );
        assert_eq!(ax.top_features.len(), 3);
        // Real training takes at the generated length: one clip per
        // value, real motion, so smooth as the held-out takes are.
        let rc = r.real_chained.as_ref().unwrap();
        assert_eq!(rc.clips, r.labels, "{rc:?}");
        assert!(
            rc.fid_k.is_some_and(|x| x.is_finite() && x >= 0.0),
            "{rc:?}"
        );
        assert!(
            rc.fid_g.is_some_and(|x| x.is_finite() && x >= 0.0),
            "{rc:?}"
        );
        assert!((0.5..2.0).contains(&rc.accel_ratio), "{rc:?}");
        assert!((0.5..2.0).contains(&rc.jerk_ratio), "{rc:?}");
        assert!(rc.diversity > 0.0, "{rc:?}");
        // The bootstrap range of FID over the generated clips is ordered.
        if let Some([lo, hi]) = r.fid_k_range {
            assert!(lo.is_finite() && lo >= 0.0 && lo <= hi, "{r:?}");
        }
        assert!((0.0..=1.0).contains(&r.frozen) && (0.0..=1.0).contains(&r.cond_acc));
        // The held-out clips' own still windows, by the same test: the same
        // for every row, and rare in real dance.
        assert_eq!(r.frozen_real, rows[0].frozen_real, "{r:?}");
        assert!((0.0..0.2).contains(&r.frozen_real), "{r:?}");
        // One accuracy per asked-for value; each clip has the same number
        // of judge windows, so their mean is the row's.
        assert_eq!(r.cond_acc_by_label.len(), r.labels, "{r:?}");
        let mean = r
            .cond_acc_by_label
            .values()
            .map(|a| a.generated)
            .sum::<f64>()
            / r.labels as f64;
        assert!((mean - r.cond_acc).abs() < 1e-9, "{r:?}");
        assert!(r
            .cond_acc_by_label
            .values()
            .all(|a| a.real.map_or(true, |x| (0.0..=1.0).contains(&x))));
        assert!(r.accel_ratio.is_finite() && r.jerk_ratio.is_finite());
        // The judge, fitted on real training windows, names real held-out
        // genres far above chance (1 in 10).
        assert!(r.cond_acc_real > 0.3, "{r:?}");
        assert!(r.diversity_real > 0.0);
        // Held-out real frames sit inside the training frames' tilt and
        // floor bands (1 % outside by construction, give or take the split).
        assert!(r.tilt_out_real < 0.05 && r.floor_out_real < 0.05, "{r:?}");
        assert!((0.0..=1.0).contains(&r.tilt_out) && (0.0..=1.0).contains(&r.floor_out));
    }
    // Each row names its sampling and root; the feet's rows differ from
    // the model's in the height alone, so everything measured root-relative
    // or from the tokens is the same.
    assert_eq!(rows[0].sampling, "greedy");
    assert_eq!(rows[1].sampling, "greedy +root-from-feet");
    assert_eq!(
        rows[2].sampling,
        "t=1 top_k=0 top_p=0.95 keep_near=2 max_jump=48"
    );
    for p in rows.chunks(2) {
        assert_eq!(p[0].cond_acc, p[1].cond_acc);
        assert!((p[0].jerk_ratio - p[1].jerk_ratio).abs() < 1e-9 * p[0].jerk_ratio.max(1.0));
    }
    // Held-out lengths: clip k of a label lasts as long as the label's
    // k-th held-out segment (whole takes shorter than --seconds, pieces of
    // --seconds from longer ones), so the generated mean is theirs.
    let (val, _) =
        choreo::eval::generate::read_split(model.vocabulary(), &dir, 0.1, &mut |_| {}).unwrap();
    let seconds = 12.0;
    let cap = (seconds * 20.0) as usize;
    let mut first: BTreeMap<String, usize> = BTreeMap::new();
    for c in &val {
        let n = c.tokens.len() / model.vocabulary().frame_len();
        if let Some(g) = c.labels.get("genre") {
            first
                .entry(g.clone())
                .or_insert(if n < cap { n } else { cap });
        }
    }
    let want = first.values().sum::<usize>() as f64 / first.len() as f64 / 20.0;
    let matched = eval_generate(
        &model,
        &dir,
        &GenOptions {
            seconds,
            held_out_lengths: true,
            samplings: vec![Sampling::default()],
            root_from_feet: vec![false],
            ..o.clone()
        },
        &mut |_| {},
    )
    .unwrap();
    assert!(
        (matched[0].seconds_generated - want).abs() < 1e-9,
        "{} vs {want}",
        matched[0].seconds_generated
    );
    assert!(
        first.values().any(|&n| n < cap),
        "no held-out clip shorter than {seconds} s"
    );
    // Style exemplars from the training side only: none of their sources
    // is a held-out clip; rows with and without them, side by side.
    let (val, train) =
        choreo::eval::generate::read_split(model.vocabulary(), &dir, 0.1, &mut |_| {}).unwrap();
    let seqs: Vec<_> = train
        .into_iter()
        .map(|c| (c.name, c.labels, c.tokens))
        .collect();
    let ex = choreo::lm::exemplars::Exemplars::build(
        &seqs,
        model.vocabulary(),
        &["genre".to_string()],
        1.0,
        1,
        None,
        choreo::lm::exemplars::SpanChoice::default(),
    )
    .unwrap();
    assert!(!ex.is_empty());
    assert!(ex
        .items
        .iter()
        .all(|e| val.iter().all(|v| !v.name.ends_with(&e.source))));
    // The file name only, not the path it was read from.
    assert!(ex.items.iter().all(|e| !e.source.contains('/')));
    let with = GenOptions {
        label_kind: "genre".into(),
        per_label: 1,
        seconds: 2.0,
        held_out_lengths: false,
        samplings: vec![Sampling::recommended(1)],
        val_fraction: 0.1,
        exemplars: Some(ex),
        exemplar_modes: vec![false, true],
        candidates: vec![1],
        rank_every: 0,
        root_from_feet: vec![false],
        pin_feet: vec![false],
    };
    let rows2 = eval_generate(&model, &dir, &with, &mut |_| {}).unwrap();
    let names: Vec<&str> = rows2.iter().map(|r| r.sampling.as_str()).collect();
    assert_eq!(
        names,
        [
            "t=1 top_k=0 top_p=0.95 keep_near=2 max_jump=48",
            "t=1 top_k=0 top_p=0.95 keep_near=2 max_jump=48 +exemplar"
        ]
    );
    // Refused, each naming what is wrong: exemplars the model does not
    // have; a kind it is not conditioned on; best of N with no class heads
    // to rank by; a folder with no motion.
    let empty = tempfile::tempdir().unwrap();
    let refusals = [
        (
            GenOptions {
                samplings: vec![Sampling::recommended(1)],
                exemplar_modes: vec![true],
                ..o.clone()
            },
            dir.as_path(),
            "exemplars.json",
        ),
        (
            GenOptions {
                label_kind: "dancer".into(),
                ..o.clone()
            },
            dir.as_path(),
            "dancer",
        ),
        (
            GenOptions {
                candidates: vec![2],
                ..o.clone()
            },
            dir.as_path(),
            "candidates",
        ),
        (
            GenOptions {
                candidates: vec![2],
                rank_every: 20,
                ..o.clone()
            },
            dir.as_path(),
            "rank_every",
        ),
        (o.clone(), empty.path(), "no readable motion"),
    ];
    for (opts, folder, want) in refusals {
        let e = eval_generate(&model, folder, &opts, &mut |_| {})
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains(want), "{want}: {e}");
    }
}

/// Closed-form class heads: fitted on the exported model's mean states of
/// a corpus whose styles differ in swing amplitude, written into the
/// graph (write_model reloads it and checks its classify against the fit
/// on every held-out window), and they tell the held-out styles apart
/// where the untrained gradient heads cannot.
#[test]
fn closed_form_heads_are_fitted_and_written_into_the_graph() {
    use choreo::lm::frame_runtime::FrameSession;
    use choreo::train::frame_heads as fh;
    let v = vocab();
    let net = FrameNet::new(config(&v), &Device::Cpu).unwrap();
    let dir = export(&net, &v);
    let motions: Vec<(String, Motion)> = (0..10)
        .map(|i| {
            let (style, amp) = if i % 2 == 0 {
                ("happy", 1.0)
            } else {
                ("sad", 0.3)
            };
            let m = sine_motion_amp(300, i as f64 * 0.7, style, amp);
            ("synthetic".to_string(), m)
        })
        .collect();
    let c = data::build(motions, &v, 0.3, true, DataInfo::default()).unwrap();
    let fl = v.frame_len();
    let session = FrameSession::load(dir.path()).unwrap();
    let train = fh::read_windows(&session, &c.train, fl, v.bins, true, 2).unwrap();
    let held = fh::read_windows(&session, &c.val, fl, v.bins, false, 2).unwrap();
    assert!(train.len() >= 2 * c.train.len(), "mirrors read too");
    assert!(!held.is_empty());
    let out = tempfile::tempdir().unwrap();
    let tract = choreo::lm::engine::Engine::tract();
    // A head on the state alone, then on the state and the pose statistics
    // (the graph gains a pose path), then that again (only new weights).
    for (f, from) in [
        (fh::Features::State, dir.path()),
        (fh::Features::StateAndPose, dir.path()),
        (fh::Features::StateAndPose, out.path()),
    ] {
        let (kinds, heads) = fh::fit_heads(&session, &train, &held, f).unwrap();
        assert_eq!(kinds.len(), 1);
        let k = &kinds[0];
        assert_eq!(k.held_out_windows, held.len());
        // An untrained network's states barely see the swing; the pose
        // statistics do.
        let posed = f == fh::Features::StateAndPose;
        assert!(
            !posed || k.new_head >= 0.99,
            "the new head on held-out windows: {k:?}"
        );
        let report = serde_json::json!({"kinds": kinds});
        let to = tempfile::tempdir().unwrap();
        fh::write_model(from, to.path(), &heads, &report, &held, f, &tract).unwrap();
        // The written model classifies through its own graph, as the server does.
        let written = FrameSession::load(to.path()).unwrap();
        for w in held.iter().filter(|_| posed) {
            let logits = written.classify(&w.values).unwrap();
            let want = if w.labels["style"] == "happy" { 0 } else { 1 };
            assert!(
                logits[0][want] > logits[0][1 - want],
                "{:?} for {}",
                logits[0],
                w.labels["style"]
            );
        }
        for e in std::fs::read_dir(to.path()).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), out.path().join(e.file_name())).unwrap();
        }
    }
    // A state-only head cannot silently drop the pose path.
    let (_, heads) = fh::fit_heads(&session, &train, &held, fh::Features::State).unwrap();
    let to = tempfile::tempdir().unwrap();
    let err = fh::write_model(
        out.path(),
        to.path(),
        &heads,
        &serde_json::json!({}),
        &held,
        fh::Features::State,
        &tract,
    )
    .unwrap_err();
    assert!(err.to_string().contains("pose path"), "{err}");
    // The original folder is untouched.
    let again = FrameSession::load(dir.path()).unwrap();
    assert_eq!(again.manifest.global_sha256, session.manifest.global_sha256);
}

#[test]
fn corpus_weights_change_the_draws_and_bad_ones_are_refused() {
    let v = vocab();
    let mut c = corpus(&v);
    let fl = v.frame_len();
    for (i, s) in c.train.iter_mut().enumerate() {
        s.corpus = if i % 2 == 0 { "a" } else { "b" }.to_string();
    }
    let frames = |name: &str| -> f64 {
        c.train
            .iter()
            .filter(|s| s.corpus == name)
            .map(|s| s.frames(fl) as f64)
            .sum()
    };
    let (fa, fb) = (frames("a"), frames("b"));
    let plain = FrameData::new(&c.train, fl).shares(&c.train);
    assert!((plain["a"] - fa / (fa + fb)).abs() < 1e-9, "{plain:?}");
    let w: BTreeMap<String, f64> = [("b".to_string(), 3.0)].into();
    let weighted = FrameData::weighted(&c.train, fl, &w)
        .unwrap()
        .shares(&c.train);
    assert!(
        (weighted["b"] - 3.0 * fb / (fa + 3.0 * fb)).abs() < 1e-3,
        "{weighted:?}"
    );
    assert!((weighted["a"] + weighted["b"] - 1.0).abs() < 1e-9);
    // Draws follow the shares.
    let d = FrameData::weighted(&c.train, fl, &w).unwrap();
    let total = *d.cum.last().unwrap();
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(1);
    let n = 20_000;
    let b = (0..n)
        .filter(|_| {
            let r = rand::Rng::gen_range(&mut rng, 0..total);
            c.train[d.cum.partition_point(|&x| x <= r)].corpus == "b"
        })
        .count();
    assert!((b as f64 / n as f64 - weighted["b"]).abs() < 0.02);
    for (bad, says) in [
        (
            ("cmu", 2.0),
            "no training sequence comes from corpus \"cmu\"",
        ),
        (("a", 0.0), "must be a positive number"),
        (("a", f64::NAN), "must be a positive number"),
    ] {
        let w: BTreeMap<String, f64> = [(bad.0.to_string(), bad.1)].into();
        let e = FrameData::weighted(&c.train, fl, &w)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("--corpus-weight") && e.contains(says), "{e}");
    }
}

#[test]
fn balance_gives_every_value_of_a_kind_the_same_share() {
    let v = vocab();
    let mut c = corpus(&v);
    let fl = v.frame_len();
    assert!(c.train.len() >= 4, "{} training sequences", c.train.len());
    // One short "run" take, the rest long "walk" takes, and one sequence
    // without a content label at all.
    for (i, s) in c.train.iter_mut().enumerate() {
        s.labels.remove("content");
        match i {
            0 => {
                s.tokens.truncate(s.tokens.len() / 4 / fl * fl);
                s.labels.insert("content".into(), "run".into());
            }
            1 => {}
            _ => {
                s.labels.insert("content".into(), "walk".into());
            }
        }
    }
    let share = |d: &FrameData, i: usize| -> f64 {
        let prev = if i == 0 { 0 } else { d.cum[i - 1] };
        (d.cum[i] - prev) as f64 / *d.cum.last().unwrap() as f64
    };
    let plain = FrameData::new(&c.train, fl);
    let b = FrameData::balanced(&c.train, fl, &BTreeMap::new(), Some("content")).unwrap();
    let n = c.train.len();
    let walk: f64 = (2..n).map(|i| share(&b, i)).sum();
    // Before: the run take is a small share; after: run = walk.
    assert!(share(&plain, 0) < 0.5 * (2..n).map(|i| share(&plain, i)).sum::<f64>());
    assert!(
        (share(&b, 0) - walk).abs() < 1e-3,
        "run {} walk {walk}",
        share(&b, 0)
    );
    // The unlabelled sequence keeps its length-weighted share, and walks
    // keep their proportions to each other.
    assert!((share(&b, 1) - share(&plain, 1)).abs() < 1e-3);
    let ratio = |d: &FrameData| share(d, 2) / share(d, 3);
    assert!((ratio(&b) - ratio(&plain)).abs() < 1e-3);
    // Unbalanced draws are unchanged by the new code path.
    assert_eq!(
        FrameData::balanced(&c.train, fl, &BTreeMap::new(), None)
            .unwrap()
            .cum,
        plain.cum
    );
    let e = FrameData::balanced(&c.train, fl, &BTreeMap::new(), Some("genre"))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("--balance") && e.contains("\"genre\""), "{e}");
}

#[test]
fn a_run_from_an_export_records_its_parents_time_and_licences() {
    let v = vocab();
    let c = corpus(&v);
    let net = trained(&v, &c, 2);
    let dir = tempfile::tempdir().unwrap();
    let data = DataInfo {
        licences: vec!["A: CC BY 4.0".into()],
        ..DataInfo::default()
    };
    frame_export::export(
        &net,
        &v,
        data,
        BTreeMap::new(),
        serde_json::json!({
            "steps": 7,
            "train_seconds": 10.0,
            "total_train_seconds": 30.0,
            "parent": {"steps": 3, "train_seconds": 20.0,
                       "data": {"licences": ["B: CC BY-NC 4.0"]}},
        }),
        dir.path(),
    )
    .unwrap();
    let (_, _, _, lineage) = fr::init_source(dir.path(), &Device::Cpu).unwrap();
    assert_eq!(lineage["steps"], 7);
    assert_eq!(fr::lineage_seconds(Some(&lineage)), 30.0);
    assert!(!lineage
        .to_string()
        .contains(&dir.path().display().to_string()));
    let child = DataInfo {
        licences: vec!["C: free".into(), "A: CC BY 4.0".into()],
        ..DataInfo::default()
    };
    assert_eq!(
        fr::licences_with_parents(&child, Some(&lineage)),
        vec!["A: CC BY 4.0", "B: CC BY-NC 4.0", "C: free"]
    );
}

/// A deeper model started from an export (`--init-from` with more
/// `--global-layers`): the parent's weights load, the blocks it lacks start
/// as the identity, so the grown model's held-out bits are its parent's;
/// one step of training then moves the new blocks.
#[test]
fn a_model_grown_by_blocks_starts_where_its_parent_ended() {
    let v = vocab();
    let c = corpus(&v);
    let dev = Device::Cpu;
    let parent = trained(&v, &c, 3);
    let dir = export(&parent, &v);
    let (_, t, file, _) = fr::init_source(dir.path(), &dev).unwrap();
    let mut cfg = parent.cfg.clone();
    cfg.global_layers += 1;
    let grown = FrameNet::new(cfg, &dev).unwrap();
    let fresh = grown.params.load_matching(&t, &file).unwrap();
    let new_block = format!("g{}", parent.cfg.global_layers);
    assert!(fresh.contains(&format!("{new_block}.q.w")), "{fresh:?}");
    assert_eq!(
        grown.params.zero_fresh_blocks(&fresh).unwrap(),
        vec![new_block.clone()]
    );
    let bits = |n: &FrameNet| {
        fr::evaluate(n, &v, &c.val, v.frame_len(), usize::MAX, &dev)
            .unwrap()
            .bits_per_frame
    };
    let (a, b) = (bits(&parent), bits(&grown));
    assert!((a - b).abs() < 1e-4 * a, "parent {a} bits/frame, grown {b}");
    // Training moves the new block's zeroed projection.
    let s = settings(1);
    let d = FrameData::new(&c.train, v.frame_len());
    let mut opt = AdamW::new(s.lr, s.weight_decay);
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(9);
    fr::train_step(
        &grown,
        &mut opt,
        &v,
        &d,
        grown.cfg.max_frames,
        &s,
        &mut rng,
        &dev,
    )
    .unwrap();
    let o = grown.params.w(&format!("{new_block}.o.w"));
    let moved = o
        .abs()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!(moved > 0.0, "the new block's output projection stayed zero");
    // A block only partly missing (here a list naming just its output
    // projection) is left as it is.
    let g0 = || -> Vec<f32> {
        let w = grown.params.w("g0.o.w");
        w.flatten_all().unwrap().to_vec1().unwrap()
    };
    let before = g0();
    assert!(grown
        .params
        .zero_fresh_blocks(&["g0.o.w".to_string()])
        .unwrap()
        .is_empty());
    let after = g0();
    assert_eq!(before, after);
    assert!(before.iter().any(|&x| x != 0.0));
}

/// A model exported without class heads (a run without --classify) gets
/// head slots for the kinds `fit-heads --classify` names; its other
/// weights travel unchanged (checked inside against the weights read
/// back), so its language-model answers are the model's.
#[test]
fn head_slots_are_added_to_a_model_without_heads() {
    use choreo::lm::frame_runtime::FrameSession;
    use choreo::train::frame_heads as fh;
    let v = vocab();
    let bare = FrameConfig {
        classes: vec![],
        ..config(&v)
    };
    let net = FrameNet::new(bare, &Device::Cpu).unwrap();
    let dir = export(&net, &v);
    // An exemplars file travels with the model (a valid one: the session
    // loads it, for sampling.matching).
    let ex =
        serde_json::json!({"fps": v.fps, "frame_len": v.frame_len(), "seconds": 1.0, "items": []});
    std::fs::write(dir.path().join("exemplars.json"), ex.to_string()).unwrap();
    let tract = choreo::lm::engine::Engine::tract();
    let out = tempfile::tempdir().unwrap();
    let none: [String; 0] = [];
    assert!(!fh::add_head_slots(dir.path(), &none, out.path(), &tract).unwrap());
    let kinds = ["style".to_string()];
    assert!(fh::add_head_slots(dir.path(), &kinds, out.path(), &tract).unwrap());
    let s = FrameSession::load(out.path()).unwrap();
    assert_eq!(s.config().classes.len(), 1);
    assert_eq!(s.config().classes[0].0, "style");
    assert!(out.path().join("exemplars.json").is_file());
    // Asked again for the heads it now has: nothing to do.
    let again = tempfile::tempdir().unwrap();
    assert!(!fh::add_head_slots(out.path(), &kinds, again.path(), &tract).unwrap());
    // A kind the vocabulary has no values for is refused, naming the flag.
    let e = fh::add_head_slots(dir.path(), &["tempo".to_string()], again.path(), &tract)
        .err()
        .unwrap();
    assert!(format!("{e:#}").contains("--classify"), "{e:#}");
}

#[test]
fn an_older_local_graph_draws_candidates_one_at_a_time_until_upgraded() {
    use choreo::lm::frame_runtime::FrameSession;
    use prost::Message;
    use tract_onnx::pb::{tensor_shape_proto::dimension::Value as Dim, type_proto::Value};
    let v = vocab();
    let c = corpus(&v);
    let net = trained(&v, &c, 20);
    let dir = export(&net, &v);
    assert!(FrameSession::load(dir.path()).unwrap().batches());
    // The local graph as exports before the batch dimension wrote it:
    // every batch dimension fixed at 1 (the manifest's hash follows).
    let path = dir.path().join("local.onnx");
    let mut m = tract_onnx::pb::ModelProto::decode(&*std::fs::read(&path).unwrap()).unwrap();
    let g = m.graph.as_mut().unwrap();
    let mut fixed = 0;
    for vi in g.input.iter_mut().chain(g.output.iter_mut()) {
        if let Some(Value::TensorType(t)) = vi.r#type.as_mut().and_then(|t| t.value.as_mut()) {
            for d in t.shape.as_mut().unwrap().dim.iter_mut() {
                if matches!(&d.value, Some(Dim::DimParam(p)) if p == "batch") {
                    d.value = Some(Dim::DimValue(1));
                    fixed += 1;
                }
            }
        }
    }
    assert!(fixed >= 6, "{fixed} batch dimensions");
    let bytes = m.encode_to_vec();
    let mf = dir.path().join("manifest.json");
    let text = std::fs::read_to_string(&mf).unwrap();
    let j: serde_json::Value = serde_json::from_str(&text).unwrap();
    let old = j["local_sha256"].as_str().unwrap().to_string();
    let new = choreo::lm::manifest::sha256_hex(&bytes);
    std::fs::write(&path, &bytes).unwrap();
    std::fs::write(&mf, text.replace(&old, &new)).unwrap();
    // On the runtime's run of the graph (choreo's local kernel batches
    // any graph it reproduces: checked on one row here).
    let graph =
        choreo::lm::engine::Engine::tract().with_local_step(choreo::lm::engine::LocalStep::Graph);
    assert!(!FrameSession::load_with(dir.path(), &graph)
        .unwrap()
        .batches());
    let k = FrameSession::load(dir.path()).unwrap();
    assert_eq!(k.local_step_on(), "kernel");
    assert!(k.batches());

    // It loads and draws four candidates a frame, one after another.
    let fl = v.frame_len();
    let sampling = Sampling {
        temperature: 1.0,
        top_p: 1.0,
        draws: 4,
        seed: 3,
        ..Sampling::default()
    };
    let mut labels = Labels::new();
    labels.insert("style".into(), "happy".into());
    let run = || -> Vec<u32> {
        let model = MotionModel::load_with(dir.path(), &graph).unwrap();
        let mut g = model.generator(&labels, &[], sampling.clone()).unwrap();
        (0..30)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect()
    };
    let before = run();
    assert_eq!(before.len(), 30 * fl);
    assert_eq!(before, run(), "one seed, one clip");

    // `choreo-train upgrade-frame`: the same weights, now batched; the
    // logits match the old graph's, one at a time and side by side.
    let (one, side) = frame_export::upgrade_local(dir.path()).unwrap().unwrap();
    eprintln!("upgraded: {one:.1e} one at a time, {side:.1e} batched");
    assert!(one < 1e-6 && side < 1e-4, "{one} {side}");
    assert!(FrameSession::load_with(dir.path(), &graph)
        .unwrap()
        .batches());
    assert!(frame_export::upgrade_local(dir.path()).unwrap().is_none());
    let after = run();
    assert_eq!(after.len(), 30 * fl);
    assert_eq!(after, run(), "one seed, one clip");
    assert!(after
        .chunks(fl)
        .all(|f| f[..fl - 1].iter().all(|&t| (t as usize) < v.bins)));
}

/// The bundled frame model's local graph is as this exporter writes it
/// (`choreo-train upgrade-frame` leaves it alone), and its weights read
/// back from the graph (the fused query/key/value layers split) are the
/// ones the local graph holds: re-exporting them gives the same bytes.
#[test]
fn the_bundled_local_graph_is_as_the_exporter_writes_it() {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(&src).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
    }
    assert!(
        frame_export::upgrade_local(dir.path()).unwrap().is_none(),
        "models/default/local.onnx is not as the exporter writes it: run `choreo-train upgrade-frame --model models/default`"
    );
    let c = choreo::lm::frame_runtime::FrameSession::load(dir.path())
        .unwrap()
        .config()
        .clone();
    let d = c.d_local;
    let t = frame_export::graph_weights(&dir.path().join("local.onnx"), &Device::Cpu).unwrap();
    for l in 0..c.local_layers {
        for p in ["q", "k", "v"] {
            assert_eq!(t[&format!("l{l}.{p}.w")].dims(), &[d, d]);
            assert_eq!(t[&format!("l{l}.{p}.b")].dims(), &[d]);
        }
        assert!(!t.contains_key(&format!("l{l}.qkv.w")));
    }
}

/// `choreo-train train --resume --steps N`: the flat GPT's run goes on to
/// the new total (the frame model's resume always did), and the saved
/// schedule says so; without `--steps` a finished run stays finished.
#[test]
fn a_resumed_flat_run_takes_a_new_total() {
    use choreo::lm::{Objective, PosScheme};
    use choreo::train::flat_run::{train, FlatRun};
    let v = vocab();
    let dir = tempfile::tempdir().unwrap();
    let run = |resume: bool, steps: Option<usize>| FlatRun {
        out: dir.path().to_path_buf(),
        init: None,
        resume,
        d_model: 16,
        layers: 1,
        heads: 2,
        frames: 2,
        positions: PosScheme::FrameSlot,
        objective: Objective::Causal,
        joints: 24,
        cond: vec!["style".into()],
        classify: vec![],
        steps,
        batch: 2,
        lr: 1e-3,
        dropout: 0.0,
        eval_every: 2,
        seed: 3,
        max_seconds: 0.0,
        corpus_weights: Default::default(),
        export: false,
        lr_sweep: false,
    };
    let engine = choreo::lm::engine::Engine::tract();
    // A corpus weight for a corpus the run does not read is refused by name.
    let mut bad = run(false, Some(2));
    bad.corpus_weights.insert("nope".into(), 2.0);
    let e = train(&bad, |_, _| Ok((v.clone(), corpus(&v))), &engine)
        .err()
        .expect("an unknown corpus is refused")
        .to_string();
    assert!(e.contains("--corpus-weight") && e.contains("nope"), "{e}");
    let go = |r: FlatRun| {
        let v = v.clone();
        train(&r, move |_, _| Ok((v.clone(), corpus(&v))), &engine).unwrap()
    };
    assert_eq!(go(run(false, Some(3)))["steps"], 3);
    // A resume naming no total: the run's own, already reached.
    assert_eq!(go(run(true, None))["steps"], 3);
    // A new total: three steps more, and the checkpoint keeps it.
    assert_eq!(go(run(true, Some(6)))["steps"], 6);
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("checkpoint.json")).unwrap())
            .unwrap();
    assert_eq!(state["step"], 6);
    assert_eq!(state["settings"]["steps"], 6);
}
