//! The model runtime (`lm::engine`): the frame model and the in-betweener
//! give the same numbers on tract and on onnxruntime (`ort`, cargo feature
//! `onnxruntime`), a stream on ort equals itself for one seed, and a
//! missing or wrong library is a clear start-up error. The ort checks skip
//! with a printed reason where the library is missing, and fail under
//! `CHOREO_REQUIRE_REFS=1` (CI, which installs the onnxruntime wheel and
//! sets `ORT_DYLIB_PATH`).
#![cfg(feature = "train")]

use candle_core::Device;
use choreo::lm::engine::{Engine, LocalStep, Runtime};
use choreo::lm::frame_runtime::FrameSession;
use choreo::lm::model::MotionModel;
use choreo::lm::Sampling;
use choreo::motion::Labels;
use choreo::tokenize::vocab::Vocabulary;
use choreo::train::frame::FrameNet;

mod common;

/// A random-weight frame model, exported; its per-frame label path
/// (`g_cond_all`, zero when fresh) is made random too, so the label input
/// is compared as well.
fn exported(v: &Vocabulary) -> tempfile::TempDir {
    let net = FrameNet::new(common::small_frame_config(v, 16), &Device::Cpu).unwrap();
    let w = net.params.w("g_cond_all");
    let r = candle_core::Tensor::randn(0f32, 0.5, w.dims(), &Device::Cpu).unwrap();
    net.params["g_cond_all"].set(&r).unwrap();
    common::export_frame(&net, v)
}

/// The onnxruntime library: ORT_DYLIB_PATH, else the pip wheel's.
fn ort_lib() -> Option<std::path::PathBuf> {
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH").filter(|p| !p.is_empty()) {
        return Some(p.into());
    }
    let out = std::process::Command::new("python3")
        .args([
            "-c",
            "import onnxruntime, glob, os; print(sorted(glob.glob(os.path.join(os.path.dirname(onnxruntime.__file__), 'capi', 'libonnxruntime.so*')))[0])",
        ])
        .output()
        .ok()?;
    let s = String::from_utf8(out.stdout).ok()?;
    let p = std::path::PathBuf::from(s.trim());
    (out.status.success() && p.is_file()).then_some(p)
}

fn ort_engine() -> Option<Engine> {
    let why = match ort_lib() {
        None => "no onnxruntime library (ORT_DYLIB_PATH unset, no onnxruntime wheel)".to_string(),
        Some(p) => match Engine::new(Runtime::Ort, Some(&p)) {
            Ok(e) => return Some(e),
            Err(e) => e.to_string(),
        },
    };
    if std::env::var("CHOREO_REQUIRE_REFS").is_ok_and(|v| v == "1") {
        panic!("CHOREO_REQUIRE_REFS=1 but {why}");
    }
    eprintln!("skipped: {why}");
    None
}

fn frames(v: &Vocabulary, n: usize) -> Vec<Vec<u32>> {
    let s = v.frame_len() - 1;
    (0..n)
        .map(|f| {
            (0..s)
                .map(|k| ((180 + 7 * k + 3 * f + (f * k) % 5) % v.bins) as u32)
                .collect()
        })
        .collect()
}

#[test]
fn missing_or_bad_libraries_are_clear_errors() {
    let e = Engine::new(
        Runtime::Ort,
        Some(std::path::Path::new("/no/such/libonnxruntime.so")),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("/no/such/libonnxruntime.so") && e.contains("pip install"),
        "{e}"
    );
    assert_eq!("ort".parse::<Runtime>().unwrap(), Runtime::Ort);
    let e = "cuda".parse::<Runtime>().unwrap_err();
    assert!(e.contains("tract, ort or auto"), "{e}");
    if cfg!(feature = "onnxruntime") {
        // A file that is not a shared library.
        let junk = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(junk.path(), b"not a library").unwrap();
        let e = Engine::new(Runtime::Ort, Some(junk.path()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot load onnxruntime"), "{e}");
    } else {
        let e = Engine::new(Runtime::Ort, None).unwrap_err().to_string();
        assert!(e.contains("onnxruntime"), "{e}");
    }
}

#[test]
fn auto_takes_onnxruntime_where_its_library_loads_else_tract() {
    assert_eq!("auto".parse::<Runtime>().unwrap(), Runtime::Auto);
    let bad = std::path::Path::new("/no/such/libonnxruntime.so");
    let (e, why) = Engine::auto(Some(bad));
    assert_eq!(e.runtime(), Runtime::Tract);
    let why = why.expect("the reason onnxruntime was passed over");
    assert!(why.contains("onnxruntime"), "{why}");
    if cfg!(feature = "onnxruntime") {
        assert!(why.contains("/no/such/libonnxruntime.so"), "{why}");
    }
    // Engine::new resolves the choice the same way, and never fails on it.
    let e = Engine::new(Runtime::Auto, Some(bad)).unwrap();
    assert_eq!(e.runtime(), Runtime::Tract);
    if ort_engine().is_none() {
        return;
    }
    let p = ort_lib().expect("ort_engine found the library");
    let (e, why) = Engine::auto(Some(&p));
    assert_eq!((e.runtime(), why), (Runtime::Ort, None));
    let bundled = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    let m = MotionModel::load_with(&bundled, &e).unwrap();
    assert_eq!(m.kind(), "motion-frame-lm");
}

#[test]
fn tract_and_ort_agree_on_the_frame_model() {
    let Some(ort) = ort_engine() else { return };
    let v = common::style_vocab();
    let dir = exported(&v);
    // Both runtimes' own runs of the graphs (not choreo's local kernel,
    // which `the_local_kernel_is_the_graph` checks).
    let t = FrameSession::load_with(
        dir.path(),
        &Engine::tract().with_local_step(LocalStep::Graph),
    )
    .unwrap();
    let o = FrameSession::load_with(dir.path(), &ort.clone().with_local_step(LocalStep::Graph))
        .unwrap();
    assert_eq!((t.local_step_on(), o.local_step_on()), ("tract", "ort"));
    let mut labels = Labels::new();
    labels.insert("style".into(), "sad".into());
    let cond = t.cond(&labels).unwrap();
    let fs = frames(&v, 12);
    let a = t.teacher_forced(&cond, &fs).unwrap();
    let b = o.teacher_forced(&cond, &fs).unwrap();
    let (mut worst, mut scale) = (0f32, 0f32);
    for ((ra, aa), (rb, ab)) in a.iter().zip(&b) {
        for (x, y) in ra.iter().chain(aa).zip(rb.iter().chain(ab)) {
            worst = worst.max((x - y).abs());
            scale = scale.max(x.abs());
        }
    }
    eprintln!(
        "tract vs ort, teacher-forced logits: max |diff| {worst:.2e} (logits up to {scale:.2})"
    );
    assert!(scale > 0.01);
    assert!(worst < 1e-4, "{worst}");
    // Candidate frames side by side (the local graph's batch dimension):
    // both runtimes, against each other and against one at a time.
    assert!(t.batches() && o.batches());
    let h = t.state_after(&cond, &fs[..2]).unwrap();
    let ctx = (Some(fs[1].as_slice()), Some(fs[0].as_slice()));
    let cands = &fs[2..6];
    let one = t.local_logits(&h, ctx, cands, false).unwrap();
    let side_t = t.local_logits(&h, ctx, cands, true).unwrap();
    let side_o = o.local_logits(&h, ctx, cands, true).unwrap();
    let flat = |x: &[(Vec<f32>, Vec<f32>)]| -> Vec<f32> {
        x.iter()
            .flat_map(|(r, a)| r.iter().chain(a).copied())
            .collect()
    };
    let (one, side_t, side_o) = (flat(&one), flat(&side_t), flat(&side_o));
    let c = t.config();
    assert_eq!(one.len(), 4 * c.slots * (c.bins + c.rel_classes()));
    for (x, (y, z)) in one.iter().zip(side_t.iter().zip(&side_o)) {
        assert!((x - y).abs() < 1e-4 && (x - z).abs() < 1e-4, "{x} {y} {z}");
    }
    let ca = t.classify(&fs.concat()).unwrap();
    let cb = o.classify(&fs.concat()).unwrap();
    for (x, y) in ca.iter().flatten().zip(cb.iter().flatten()) {
        assert!((x - y).abs() < 1e-4, "{x} vs {y}");
    }
}

/// Teacher-forced logits (every slot of every frame) and candidate frames
/// side by side: the largest difference between two sessions, and the
/// largest logit.
fn local_gap(a: &FrameSession, b: &FrameSession, cond: &[f32], fs: &[Vec<u32>]) -> (f32, f32) {
    let (mut worst, mut scale) = (0f32, 0f32);
    let ta = a.teacher_forced(cond, fs).unwrap();
    let tb = b.teacher_forced(cond, fs).unwrap();
    let h = a.state_after(cond, &fs[..2]).unwrap();
    let ctx = (Some(fs[1].as_slice()), Some(fs[0].as_slice()));
    let mut pairs: Vec<(Vec<f32>, Vec<f32>)> = ta
        .into_iter()
        .zip(tb)
        .map(|((ra, aa), (rb, ab))| ([ra, aa].concat(), [rb, ab].concat()))
        .collect();
    for batched in [false, true] {
        let la = a.local_logits(&h, ctx, &fs[2..6], batched).unwrap();
        let lb = b.local_logits(&h, ctx, &fs[2..6], batched).unwrap();
        for ((ra, aa), (rb, ab)) in la.into_iter().zip(lb) {
            pairs.push(([ra, aa].concat(), [rb, ab].concat()));
        }
    }
    for (x, y) in pairs {
        assert_eq!(x.len(), y.len());
        for (x, y) in x.iter().zip(&y) {
            assert!(x.is_finite() && y.is_finite());
            worst = worst.max((x - y).abs());
            scale = scale.max(x.abs());
        }
    }
    (worst, scale)
}

#[test]
fn the_local_kernel_is_the_graph() {
    // A random-weight export and the bundled model: choreo's local kernel
    // (the default) against tract's run of the same local graph.
    let v = common::style_vocab();
    let dir = exported(&v);
    let bundled = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    for (path, fs) in [
        (dir.path().to_path_buf(), frames(&v, 12)),
        (bundled, Vec::new()),
    ] {
        let k = FrameSession::load_with(&path, &Engine::tract()).unwrap();
        let g = FrameSession::load_with(&path, &Engine::tract().with_local_step(LocalStep::Graph))
            .unwrap();
        assert_eq!((k.local_step_on(), g.local_step_on()), ("kernel", "tract"));
        let c = k.config();
        // The bundled model: mid-range frames with a slow sweep, so the
        // slots differ and the changes stay inside the window.
        let fs = if fs.is_empty() {
            (0..8)
                .map(|f| {
                    (0..c.slots)
                        .map(|s| (c.bins / 2 + (3 * s + 2 * f) % 20) as u32)
                        .collect()
                })
                .collect()
        } else {
            fs
        };
        let mut labels = Labels::new();
        labels.insert("style".into(), "sad".into());
        let cond = k.cond(&labels).unwrap();
        let (worst, scale) = local_gap(&k, &g, &cond, &fs);
        eprintln!(
            "{}: kernel vs tract graph, local logits: max |diff| {worst:.2e} (logits up to {scale:.2})",
            path.display()
        );
        assert!(scale > 0.01);
        assert!(worst < 1e-4, "{worst}");
    }
}

#[test]
fn a_labelled_stream_on_the_kernel_is_the_stream_on_the_graph() {
    // The bundled model at the style default (four candidates a frame,
    // motion matching, posture pull): one seed, the same frames.
    let bundled = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    let mut labels = Labels::new();
    labels.insert("style".into(), "happy".into());
    let run = |engine: Engine| -> Vec<u32> {
        let model = MotionModel::load_with(&bundled, &engine).unwrap();
        let mut s = Sampling::recommended(7);
        model.fill_defaults(&labels, &mut s, Default::default());
        assert_eq!(s.draws, 4);
        let fl = model.vocabulary().frame_len();
        let mut g = model.generator(&labels, &[], s).unwrap();
        (0..30)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect()
    };
    let kernel = run(Engine::tract());
    assert_eq!(
        kernel,
        run(Engine::tract().with_local_step(LocalStep::Graph))
    );
}

#[test]
fn a_local_kernel_that_differs_from_its_graph_is_not_used() {
    use choreo::lm::engine::{local_kernel, GraphSpec};
    use choreo::lm::frame::{local_inputs, local_outputs, FrameManifest};
    let v = common::style_vocab();
    let dir = exported(&v);
    let (m, _, bytes) = FrameManifest::load(dir.path()).unwrap();
    let c = &m.config;
    let graph = Engine::tract()
        .load(
            &bytes,
            &GraphSpec {
                inputs: &local_inputs(c),
                outputs: local_outputs(c).len(),
                file: "local.onnx",
                f32_shapes: &[],
                batch: Some(choreo::lm::frame::LOCAL_BATCH),
            },
        )
        .unwrap();
    let eps = c.ln_eps as f32;
    let (_, gap) =
        local_kernel::checked(graph.as_ref(), &bytes, (c.local_layers, c.local_heads, eps))
            .unwrap();
    assert!(gap < local_kernel::PROBE_TOLERANCE);
    // A LayerNorm epsilon far off: the probe sees the outputs move and
    // keeps the graph. The heads split otherwise: refused too (the graph
    // itself will not take caches of that shape).
    let why = local_kernel::checked(graph.as_ref(), &bytes, (c.local_layers, c.local_heads, 0.5))
        .err()
        .expect("a far-off epsilon passed the probe");
    assert!(why.contains("from the graph's"), "{why}");
    let heads = c.local_heads / 2;
    assert!(
        local_kernel::checked(graph.as_ref(), &bytes, (c.local_layers, heads, eps)).is_err(),
        "{heads} heads passed the probe"
    );
    // One block fewer than the graph has: named.
    let why = local_kernel::checked(
        graph.as_ref(),
        &bytes,
        (c.local_layers - 1, c.local_heads, eps),
    )
    .err()
    .unwrap();
    assert!(why.contains("more than the manifest's"), "{why}");
}

#[test]
fn an_ort_stream_is_the_one_shot_output_for_one_seed() {
    let Some(ort) = ort_engine() else { return };
    let v = common::style_vocab();
    let dir = exported(&v);
    let model = MotionModel::load_with(dir.path(), &ort).unwrap();
    let fl = v.frame_len();
    let sampling = Sampling {
        temperature: 1.0,
        top_k: 0,
        top_p: 0.95,
        seed: 4,
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
    // Past the context, so the window slides.
    let n = 2 * model.context_frames() + 3;
    let run = || -> Vec<u32> {
        let mut g = model
            .generator(&Labels::new(), &[], sampling.clone())
            .unwrap();
        (0..n)
            .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
            .collect()
    };
    let a = run();
    assert_eq!(a, run());
    assert_eq!(a.len(), n * fl);
    // Two generators at once share the graph's session pool.
    let mut g1 = model
        .generator(&Labels::new(), &[], sampling.clone())
        .unwrap();
    let mut g2 = model
        .generator(&Labels::new(), &[], sampling.clone())
        .unwrap();
    let f1 = g1.next_frame(&vec![None; fl]).unwrap();
    let f2 = g2.next_frame(&vec![None; fl]).unwrap();
    assert_eq!(f1, f2);
    assert_eq!(f1, a[..fl]);
}

#[test]
fn tract_and_ort_agree_on_the_bundled_inbetweener() {
    use choreo::lm::inbetween::Inbetweener;
    let Some(ort) = ort_engine() else { return };
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/inbetween");
    let t = Inbetweener::load_with(&dir, &Engine::tract()).unwrap();
    let o = Inbetweener::load_with(&dir, &ort).unwrap();
    let cfg = t.config();
    let n = cfg.window * cfg.in_dim();
    // Three windows (one batch) of smooth, bounded inputs.
    let xs: Vec<Vec<f32>> = (0..3)
        .map(|w| {
            (0..n)
                .map(|i| (0.37 * i as f32 + w as f32).sin() * 0.5)
                .collect()
        })
        .collect();
    let a = t.run_windows(&xs).unwrap();
    let b = o.run_windows(&xs).unwrap();
    let (mut worst, mut scale) = (0f32, 0f32);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        worst = worst.max((x - y).abs());
        scale = scale.max(x.abs());
    }
    eprintln!("in-betweener tract vs ort: max |diff| {worst:.2e} (outputs up to {scale:.3})");
    assert!(scale > 1e-4);
    assert!(worst < 1e-4, "{worst}");
}

/// The thesis's flat GPT (the bundled `models/flat`, dynamic shapes) gives
/// the same logits on tract and on onnxruntime: a whole window in one step,
/// then 60 tokens at once and 30 one by one with the past cached.
#[test]
fn tract_and_ort_agree_on_the_flat_model() {
    use choreo::lm::runtime::{Kv, LmSession};
    let Some(ort) = ort_engine() else { return };
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/flat");
    let t = LmSession::load_with(&dir, &Engine::tract()).unwrap();
    let o = LmSession::load_with(&dir, &ort).unwrap();
    let cfg = t.config().clone();
    let (toks, pos) = choreo::lm::bench_window(&cfg, &t.manifest.vocabulary);
    let worst = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max)
    };
    let (wa, _) = t.step(&toks, &pos, Kv::empty(&cfg)).unwrap();
    let (wb, _) = o.step(&toks, &pos, Kv::empty(&cfg)).unwrap();
    let whole = worst(&wa.logits, &wb.logits);
    // Incremental: the first 60 tokens at once, then one by one.
    let (mut kt, mut ko) = (Kv::empty(&cfg), Kv::empty(&cfg));
    let mut step_worst = 0f32;
    let mut scale = 0f32;
    for (i, j) in std::iter::once((0, 60)).chain((60..90).map(|i| (i, i + 1))) {
        let (a, k2) = t.step(&toks[i..j], &pos[i..j], kt).unwrap();
        let (b, o2) = o.step(&toks[i..j], &pos[i..j], ko).unwrap();
        step_worst = step_worst.max(worst(&a.logits, &b.logits));
        scale = scale.max(a.logits.iter().fold(0f32, |m, x| m.max(x.abs())));
        for (x, y) in a
            .class_logits
            .iter()
            .flatten()
            .zip(b.class_logits.iter().flatten())
        {
            assert!((x - y).abs() < 1e-3, "{x} vs {y}");
        }
        (kt, ko) = (k2, o2);
    }
    eprintln!(
        "flat model, tract vs ort: whole window ({} tokens) max |diff| {whole:.2e}; incremental {step_worst:.2e} (logits up to {scale:.1})",
        toks.len()
    );
    assert!(scale > 0.1);
    assert!(whole < 1e-3 && step_worst < 1e-3, "{whole} {step_worst}");
}

/// The flat GPT has no label postures: a request that asks it to pull
/// toward them is refused naming the field, not run without the pull.
#[test]
fn the_flat_model_refuses_a_posture_pull_and_a_shorter_context() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/flat");
    let m = MotionModel::load(&dir).unwrap();
    assert!(!m.has_postures());
    let mut labels = Labels::new();
    let (kind, values) = m.vocabulary().labels.iter().next().unwrap();
    labels.insert(kind.clone(), values.iter().next().unwrap().clone());
    let pulled = Sampling {
        posture: 2.0,
        ..Sampling::recommended(1)
    };
    let e = m.generator(&labels, &[], pulled).err().unwrap().to_string();
    assert!(e.contains("sampling.posture") && e.contains("flat"), "{e}");
    // Nor can it read less than its window (sampling.context).
    let shorter = Sampling {
        context: 4,
        ..Sampling::recommended(1)
    };
    let e = m
        .generator(&labels, &[], shorter)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("sampling.context") && e.contains("flat"), "{e}");
    // Without the pull it generates.
    let mut g = m.generator(&labels, &[], Sampling::recommended(1)).unwrap();
    let fl = m.vocabulary().frame_len();
    assert_eq!(g.next_frame(&vec![None; fl]).unwrap().len(), fl);
}

#[test]
fn the_skate_price_keeps_planted_feet_stiller() {
    // The bundled model, genre HO at its default (four candidates a
    // frame), three seeds of 120 frames each with and without the price:
    // the ankles' ground speed while within 3 cm of the clip's floor (what
    // `eval generate`'s skating column measures), against the same count
    // of frames.
    let bundled = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    let model = MotionModel::load(&bundled).unwrap();
    let v = model.vocabulary().clone();
    let fl = v.frame_len();
    let mut labels = Labels::new();
    labels.insert("genre".into(), "HO".into());
    let slide = |skate: f64| -> (f64, usize) {
        let (mut sum, mut n) = (0.0, 0usize);
        for seed in 0..3 {
            let mut s = Sampling::recommended(seed);
            model.fill_defaults(&labels, &mut s, Default::default());
            assert_eq!(s.draws, 4);
            s.skate = skate;
            let mut g = model.generator(&labels, &[], s).unwrap();
            let toks: Vec<u32> = (0..120)
                .flat_map(|_| g.next_frame(&vec![None; fl]).unwrap())
                .collect();
            let m = v.decode_motion(&toks, "clip").unwrap();
            let p = m.positions();
            let j = m.joints();
            for name in ["Left_Ankle", "Right_Ankle"] {
                let a = m.skeleton.index_of(name).unwrap();
                let floor = (0..m.frames())
                    .map(|f| p[f * j + a][1])
                    .fold(f64::INFINITY, f64::min);
                for f in 1..m.frames() {
                    let (x, y) = (p[(f - 1) * j + a], p[f * j + a]);
                    if y[1] < floor + 0.03 {
                        sum += ((y[0] - x[0]).powi(2) + (y[2] - x[2]).powi(2)).sqrt() * m.fps;
                        n += 1;
                    }
                }
            }
        }
        (sum / n.max(1) as f64, n)
    };
    let (free, nf) = slide(0.0);
    let (priced, np) = slide(10.0);
    eprintln!("planted ankles' ground speed: {free:.3} m/s ({nf} frames) without the price, {priced:.3} ({np}) with skate 10");
    assert!(nf > 50 && np > 50, "{nf} {np}");
    assert!(priced < 0.8 * free, "{priced} against {free}");
}
