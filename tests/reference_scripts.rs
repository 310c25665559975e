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
