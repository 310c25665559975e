//! The web studio in a real browser: Debian's Chromium driven by
//! playwright-core (`tests/browser/studio.mjs`) against a server holding
//! real AIST++ dances and a Bandai take, with the bundled model. Each page's
//! main path: the 3D canvas draws and moves, the console stays clean, the
//! exports download, a bad upload shows the API's error in the page, a
//! page on the allowed origin calls the API and one on another origin
//! cannot. The studio's forward kinematics is held against the server's.
//!
//! Skips with a printed reason without Chromium, Node or `web/node_modules`
//! (run `npm ci --prefix web`), and fails instead under
//! `CHOREO_REQUIRE_BROWSER=1` (CI). Screenshots go to
//! `$CHOREO_SCREENSHOTS` when it is set (README's pictures: `docs/`).

mod support;

use choreo::api::http::MotionJson;
use choreo::motion::{Motion, Skeleton};
use choreo::server::start;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn chromium() -> PathBuf {
    std::env::var_os("CHOREO_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"))
}

/// Why the browser test cannot run here, if it cannot.
fn missing(root: &Path) -> Option<String> {
    if !chromium().exists() {
        return Some(format!(
            "no Chromium at {} (apt-get install chromium, or set CHOREO_CHROMIUM)",
            chromium().display()
        ));
    }
    if Command::new("node").arg("--version").output().is_err() {
        return Some("no node on PATH".into());
    }
    if !root.join("web/node_modules/playwright-core").exists() {
        return Some("web/node_modules/playwright-core is missing (npm ci --prefix web)".into());
    }
    None
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn studio_pages_work_in_chromium() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    if let Some(why) = missing(&root) {
        if std::env::var("CHOREO_REQUIRE_BROWSER").is_ok_and(|v| v == "1") {
            panic!("CHOREO_REQUIRE_BROWSER=1 but {why}");
        }
        eprintln!("SKIP: {why}");
        return;
    }
    let Some(aist) = choreo::data::require("aistpp/motions") else {
        return;
    };
    let Some(bandai) =
        choreo::data::require("bandai/dataset-2/dataset-2_raise-up-both-hands_active_001.bvh")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cors_port = free_port();
    let cfg = choreo::server::ServeConfig {
        ingest: vec![aist, bandai],
        token: Some("studio-secret".into()),
        cors_origins: vec![format!("http://127.0.0.1:{cors_port}")],
        ..support::serve_config(dir.path())
    };
    let running = start(&cfg).await.unwrap();
    let url = format!("http://{}", running.http);
    let fk_out = dir.path().join("fk.json");
    let gltf_out = dir.path().join("gltf.json");
    let mut cmd = Command::new("node");
    cmd.arg(root.join("tests/browser/studio.mjs"))
        .args(["--url", &url, "--token", "studio-secret"])
        .args(["--cors-port", &cors_port.to_string()])
        .arg("--fk-out")
        .arg(&fk_out)
        .arg("--gltf-out")
        .arg(&gltf_out)
        .arg("--chromium")
        .arg(chromium());
    if let Some(shots) = std::env::var_os("CHOREO_SCREENSHOTS") {
        std::fs::create_dir_all(&shots).unwrap();
        cmd.arg("--shots").arg(shots);
    }
    let out = tokio::task::spawn_blocking(move || cmd.output().unwrap())
        .await
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}");
    assert!(
        out.status.success(),
        "the studio check failed:\n{}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let results: Value = serde_json::from_str(&stdout).unwrap();
    assert!(results["search_hits"].as_u64().unwrap() >= 1);
    assert!(results["generate_first_frame_ms"].as_f64().is_some());

    // The browser's forward kinematics (what the studio draws) equals the
    // server's on the same stored and generated frames, and so do the joints
    // of the API's glb as three.js's GLTFLoader and AnimationMixer pose them.
    let studio = worst_vs_server(running.http, &fk_out);
    println!("studio FK vs server FK: worst {studio:.2e} m");
    let gltf = worst_vs_server(running.http, &gltf_out);
    println!("glb in three.js (GLTFLoader + AnimationMixer) vs server FK: worst {gltf:.2e} m");
    // Both sides end in float32: about 1e-7 relative.
    assert!(
        studio < 1e-5,
        "the studio's FK differs from the server's by {studio} m"
    );
    assert!(
        gltf < 1e-5,
        "the glb as three.js plays it differs from the server's FK by {gltf} m"
    );
    running.shutdown().await.unwrap();
}

/// The largest difference (metres) between the joint positions in `path`
/// (`[{id | generated + skeleton, frames, positions}]`, from the browser)
/// and the server's FK of the same frames.
fn worst_vs_server(http: std::net::SocketAddr, path: &Path) -> f64 {
    let fk: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let mut worst = 0.0f64;
    for m in fk.as_array().unwrap() {
        // A stored motion (its data and skeleton from the server), or a
        // generated one on the model's skeleton.
        let (data, skeleton) = if m.get("generated").is_some() {
            (m["generated"].clone(), m["skeleton"].clone())
        } else {
            let id = m["id"].as_i64().unwrap();
            let (_, _, body) =
                support::exchange(http, "GET", &format!("/v1/motions/{id}"), None, None).unwrap();
            (body["motion"].clone(), body["skeleton"].clone())
        };
        let data: MotionJson = serde_json::from_value(data).unwrap();
        let skeleton: Skeleton = serde_json::from_value(skeleton).unwrap();
        let motion = Motion::new(
            "stored",
            data.fps,
            skeleton,
            data.translation,
            data.rotations.into_iter().flatten().collect(),
            Default::default(),
        )
        .unwrap();
        let pos = motion.positions();
        let j = motion.joints();
        for (f, browser) in m["frames"]
            .as_array()
            .unwrap()
            .iter()
            .zip(m["positions"].as_array().unwrap())
        {
            let f = f.as_u64().unwrap() as usize;
            for (k, p) in pos[f * j..(f + 1) * j].iter().enumerate() {
                for a in 0..3 {
                    let b = browser[k * 3 + a].as_f64().unwrap();
                    worst = worst.max((b - p[a]).abs());
                }
            }
        }
    }
    worst
}
