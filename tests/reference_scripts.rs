//! Independent references: the Python scripts in `scripts/` check choreo's
//! numbers against scipy / numpy / bvhio. They need `python3` with the
//! packages of `scripts/requirements.txt`; without them these tests skip with
//! a printed reason, unless `CHOREO_REQUIRE_REFS=1` (CI), where they fail.

use std::process::Command;

fn python_with(modules: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        let msg = format!(
            "python3 with {modules} not available (pip install -r scripts/requirements.txt)"
        );
        if std::env::var("CHOREO_REQUIRE_REFS").is_ok_and(|v| v == "1") {
            panic!("CHOREO_REQUIRE_REFS=1 but {msg}");
        }
        eprintln!("SKIP: {msg}");
    }
    ok
}

/// Run a script with the choreo binary and, when `data` names a folder of
/// the data root that must exist, the data root.
fn run_script(script: &str, data: Option<&str>) {
    let mut cmd = Command::new("python3");
    cmd.arg(format!("{}/scripts/{script}", env!("CARGO_MANIFEST_DIR")))
        .arg(env!("CARGO_BIN_EXE_choreo"));
    if let Some(rel) = data {
        let Some(dir) = choreo::data::require(rel) else {
            return;
        };
        cmd.arg(dir.parent().expect("data root"));
    }
    let out = cmd.output().expect("python3 runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{text}");
    assert!(out.status.success(), "{script} failed:\n{text}");
}

#[test]
fn rotations_agree_with_scipy() {
    if python_with("numpy, scipy") {
        run_script("check_rotations.py", None);
    }
}

#[test]
fn catmull_rom_agrees_with_scipy() {
    if python_with("numpy, scipy") {
        run_script("check_catmull_rom.py", Some("aistpp"));
    }
}

#[test]
fn sequence_whitening_agrees_with_scipy() {
    if python_with("numpy, scipy") {
        run_script("check_whiten.py", None);
    }
}

#[test]
fn gltf_output_reads_in_pygltflib() {
    if python_with("numpy, pygltflib") {
        run_script("check_gltf.py", Some("aistpp"));
    }
}

#[test]
fn bvh_output_reads_in_bvhio() {
    if python_with("numpy, bvhio") {
        run_script("check_bvh_bvhio.py", Some("aistpp"));
    }
}

#[test]
fn amass_npz_agrees_with_numpy() {
    if python_with("numpy, scipy") {
        run_script("check_amass_npz.py", Some("aistpp"));
    }
}

#[test]
fn embeddings_agree_with_scipy_and_numpy() {
    if python_with("numpy, scipy") {
        run_script("check_features.py", Some("aistpp"));
    }
}

#[test]
fn music_features_agree_with_librosa() {
    if python_with("numpy, librosa") {
        run_script("check_audio_librosa.py", Some("music"));
    }
}

/// The frame model's two step graphs in onnxruntime, driven by the Python
/// script's own cache bookkeeping, against choreo's tract runtime.
#[cfg(feature = "train")]
#[test]
fn frame_model_runtime_agrees_with_onnxruntime() {
    use choreo::lm::frame::FrameConfig;
    use choreo::lm::frame_runtime::FrameSession;
    use choreo::motion::Labels;
    use choreo::tokenize::vocab::Vocabulary;
    use choreo::train::frame::FrameNet;
    if !python_with("numpy, onnx, onnxruntime") {
        return;
    }
    let mut labels = std::collections::BTreeMap::new();
    labels.insert(
        "style".to_string(),
        ["happy", "sad"].iter().map(|s| s.to_string()).collect(),
    );
    let v = Vocabulary::new(labels);
    let cfg = FrameConfig {
        bins: v.bins,
        slots: v.frame_len() - 1,
        radius: 10,
        d_emb: 8,
        d_global: 32,
        global_layers: 2,
        global_heads: 4,
        d_local: 16,
        local_layers: 2,
        local_heads: 2,
        max_frames: 12,
        vocab_size: v.size(),
        cond_kinds: vec!["style".into()],
        classes: vec![("style".into(), vec!["happy".into(), "sad".into()])],
        ln_eps: 1e-5,
        cond_every: true,
    };
    let net = FrameNet::new(cfg, &candle_core::Device::Cpu).unwrap();
    let dir = tempfile::tempdir().unwrap();
    choreo::train::frame_export::export(
        &net,
        &v,
        Default::default(),
        Default::default(),
        serde_json::json!({}),
        dir.path(),
    )
    .unwrap();
    // Frames that move: small and large changes, escapes included.
    let frames: Vec<Vec<u32>> = (0..8u32)
        .map(|f| {
            (0..42u32)
                .map(|s| (100 + s * 5 + f * (1 + s % 7) * 3) % 360)
                .collect()
        })
        .collect();
    // A class head with a pose path (as `choreo-train fit-heads` writes):
    // the script recomputes its per-step logits in numpy from the graph's
    // weights and its own pose statistics.
    let width = 32 + 3 * 42;
    let head = choreo::train::frame_heads::Linear {
        weights: (0..2)
            .map(|c| {
                (0..width)
                    .map(|i| ((i * 7 + c * 3) % 11) as f64 / 11.0 - 0.5)
                    .collect()
            })
            .collect(),
        bias: vec![0.25, -0.5],
        centre: (0..width).map(|i| (i % 5) as f64 * 0.1).collect(),
    };
    let posed = tempfile::tempdir().unwrap();
    choreo::train::frame_heads::write_model(
        dir.path(),
        posed.path(),
        &[Some(head)],
        &serde_json::json!({}),
        &[],
        choreo::train::frame_heads::Features::StateAndPose,
        &choreo::lm::engine::Engine::tract(),
    )
    .unwrap();
    let dir = posed;
    let session = FrameSession::load(dir.path()).unwrap();
    let mut l = Labels::new();
    l.insert("style".into(), "sad".into());
    let cond = session.cond(&l).unwrap();
    let out = session.teacher_forced(&cond, &frames).unwrap();
    let values: Vec<u32> = frames.iter().flatten().copied().collect();
    let dump = serde_json::json!({
        "frames": frames,
        "cond": cond,
        "rel": out.iter().map(|x| &x.0).collect::<Vec<_>>(),
        "abs": out.iter().map(|x| &x.1).collect::<Vec<_>>(),
        "classify": session.classify(&values).unwrap(),
        "cond_none": session.cond(&Labels::new()).unwrap(),
    });
    let path = dir.path().join("dump.json");
    std::fs::write(&path, dump.to_string()).unwrap();
    let o = Command::new("python3")
        .arg(format!(
            "{}/scripts/check_frame_onnxruntime.py",
            env!("CARGO_MANIFEST_DIR")
        ))
        .arg(dir.path())
        .arg(&path)
        .output()
        .expect("python3 runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("{text}");
    assert!(
        o.status.success(),
        "check_frame_onnxruntime.py failed:\n{text}"
    );
}

#[test]
fn keypoints_and_ik_agree_with_numpy_fk() {
    if python_with("numpy, scipy") {
        run_script("check_keypoints.py", Some("aistpp"));
    }
}
