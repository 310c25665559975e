//! Rehearsal footage end to end, on keypoints made from the real AIST++
//! takes (skipped with a reason without the data; failing instead under
//! `CHOREO_REQUIRE_DATA=1`): keypoint files of both layouts and WHAM-style
//! SMPL files read and solved; ingested over REST and gRPC with a video
//! link; found from the mocap and the mocap found from them; the hit's video
//! time; a stored keypoint motion read back the way it was read in; bad
//! files refused with the file and field named.

use base64::Engine;
use choreo::api::grpc::pb;
use choreo::data::require;
use choreo::motion::io::{self, keypoints as kpio, smpl_params, ReadOptions};
use choreo::motion::keypoints::{
    joint_errors, synthesize, Keypoints, Layout, Measure, SynthOptions, Up,
};
use choreo::server::{start, ServeConfig};
use serde_json::{json, Value};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

mod support;

const TOKEN: &str = "footage-token";

fn http(addr: SocketAddr, method: &str, path: &str, body: Option<&Value>) -> (u16, Value) {
    let (status, _, v) = support::exchange(addr, method, path, body, Some(TOKEN)).unwrap();
    (status, v)
}

fn config(dir: &Path, ingest: Vec<PathBuf>) -> ServeConfig {
    ServeConfig {
        ingest,
        token: Some(TOKEN.into()),
        ..support::serve_config(dir)
    }
}

fn take(aist: &Path) -> (PathBuf, choreo::motion::Motion) {
    let p = aist.join("gJS_sFM_cAll_d02_mJS4_ch09.pkl");
    let m = io::read_path(&p, &ReadOptions::default()).unwrap().motion;
    (p, m)
}

fn noisy(m: &choreo::motion::Motion, layout: Layout, seed: u64) -> Keypoints {
    synthesize(m, &SynthOptions::noisy(layout, 30.0, seed)).unwrap()
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

#[test]
fn keypoint_and_smpl_files_read_back_close_to_the_take() {
    let Some(aist) = require("aistpp/motions") else {
        return;
    };
    let (_, m) = take(&aist);
    let truth = m.resample(30.0).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for (layout, name, bytes) in [
        (
            Layout::H36m17,
            "take.npy",
            kpio::write_npy(&noisy(&m, Layout::H36m17, 3)),
        ),
        (
            Layout::Mediapipe33,
            "take.json",
            kpio::write_json(&noisy(&m, Layout::Mediapipe33, 4)),
        ),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let read = ReadOptions {
            keypoints: Some(layout),
            fps: Some(30.0),
            ..Default::default()
        };
        let loaded = io::read_path(&path, &read).unwrap();
        let rep = loaded.footage.as_ref().unwrap();
        // Millimetres, found from the bone lengths; the dropped frames
        // (about 3 %) and low-confidence spells (about 5 %) flagged.
        assert!(
            (rep.metres_per_unit - 0.001).abs() < 0.00005,
            "{layout}: {rep:?}"
        );
        // A .npy carries no confidence, so only its missed frames are
        // flagged; the JSON's low-confidence spells are too.
        let share = rep.flagged_frames as f64 / rep.frames as f64;
        let expect = if name.ends_with(".npy") {
            0.02..0.05
        } else {
            0.06..0.10
        };
        assert!(expect.contains(&share), "{layout}: {share}");
        assert_eq!(loaded.motion.frames(), truth.frames());
        // Hinge joints within a few degrees at the median, on noisy input.
        for (joint, mut e) in joint_errors(layout, &loaded.motion, &truth, Measure::Observable) {
            e.sort_by(f64::total_cmp);
            let median = e[e.len() / 2];
            if joint.contains("Knee") || joint.contains("Elbow") {
                assert!(median < 8.0, "{layout} {joint}: median {median:.2}°");
            }
        }
    }
    // WHAM-style SMPL parameters with missed frames: bridged, same frames.
    let keep: Vec<usize> = (0..truth.frames()).filter(|f| f % 17 != 5).collect();
    let npz = smpl_params::write_npz(&truth, &keep).unwrap();
    let path = dir.path().join("wham.npz");
    std::fs::write(&path, &npz).unwrap();
    let read = ReadOptions {
        fps: Some(30.0),
        ..Default::default()
    };
    let loaded = io::read_path(&path, &read).unwrap();
    assert_eq!(loaded.format, io::Format::Smpl);
    let rep = loaded.footage.unwrap();
    assert_eq!(rep.frames, truth.frames());
    assert_eq!(rep.flagged_frames, truth.frames() - keep.len());
    for &f in &keep {
        for j in 0..24 {
            let d = choreo::motion::rotation::geodesic_axis_angle(
                loaded.motion.rot(f, j),
                truth.rot(f, j),
            );
            assert!(d < 1e-5, "frame {f} joint {j}: {d}");
        }
    }
    // Without a frame rate it is refused, naming the file and the field.
    let e = io::read_path(&path, &ReadOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("wham.npz") && e.contains("`fps`"), "{e}");
    // The same file turned: --up z reads a z-up world.
    let up = ReadOptions {
        fps: Some(30.0),
        up: Some(Up::Z),
        ..Default::default()
    };
    let turned = io::read_path(&path, &up).unwrap().motion;
    let (a, b) = (loaded.motion.positions(), turned.positions());
    let (pa, pb) = (a[24 * 10 + 15], b[24 * 10 + 15]);
    assert!((pb[1] - pa[2]).abs() < 1e-6 && (pb[2] + pa[1]).abs() < 1e-6);
}

#[test]
fn bad_keypoint_files_name_the_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let kp_read = |layout| ReadOptions {
        keypoints: Some(layout),
        fps: Some(30.0),
        ..Default::default()
    };
    let write = |name: &str, bytes: Vec<u8>| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let npy = |shape: Vec<usize>, data: Vec<f64>| io::npy::NdArray { shape, data }.to_npy(true);
    let cases: Vec<(PathBuf, ReadOptions, &str)> = vec![
        // Wrong shape for the layout.
        (
            write("wrong.npy", npy(vec![10, 16, 3], vec![0.0; 480])),
            kp_read(Layout::H36m17),
            "field `shape`",
        ),
        // No layout for a .npy.
        (
            write("nolayout.npy", npy(vec![10, 17, 3], vec![0.0; 510])),
            ReadOptions::default(),
            "field `keypoints`",
        ),
        // No frame rate.
        (
            write("nofps.npy", npy(vec![10, 17, 3], vec![0.0; 510])),
            ReadOptions {
                keypoints: Some(Layout::H36m17),
                ..Default::default()
            },
            "field `fps`",
        ),
        // Every frame missed.
        (
            write("nan.npy", npy(vec![10, 17, 3], vec![f64::NAN; 510])),
            kp_read(Layout::H36m17),
            "field `frames`",
        ),
        // Half a point missing is not a missed detection.
        (
            write("halfnan.npy", {
                let mut d = vec![0.1; 510];
                d[4] = f64::NAN;
                npy(vec![10, 17, 3], d)
            }),
            kp_read(Layout::H36m17),
            "field `keypoints`",
        ),
        // Visibility outside [0, 1].
        (
            write(
                "vis.json",
                serde_json::to_vec(&json!({"fps": 30, "frames": [vec![[0.0, 0.0, 0.0, 1.5]; 33]]}))
                    .unwrap(),
            ),
            kp_read(Layout::Mediapipe33),
            "field `frames[0][0][3]`",
        ),
        // A frame with the wrong point count.
        (
            write(
                "count.json",
                serde_json::to_vec(&json!({"fps": 30, "frames": [vec![[0.0, 0.0, 0.0]; 17]]}))
                    .unwrap(),
            ),
            kp_read(Layout::Mediapipe33),
            "field `frames[0]`",
        ),
    ];
    for (path, read, want) in cases {
        let e = io::read_path(&path, &read).err().unwrap().to_string();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        assert!(e.contains(&name) && e.contains(want), "{name}: {e}");
    }
    assert!("openpose25".parse::<Layout>().is_err());
    assert!("w".parse::<Up>().is_err());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn footage_ingested_with_video_is_found_from_mocap_and_finds_it() {
    let Some(aist) = require("aistpp/motions") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), vec![aist.clone()]))
        .await
        .unwrap();
    let (h, g) = (running.http, running.grpc);
    let (_, m) = take(&aist);
    let kp = noisy(&m, Layout::H36m17, 11);
    let body = json!({
        "motion": {"file": {"name": "rehearsal_cam1.npy", "content_base64": b64(&kpio::write_npy(&kp)),
                            "keypoints": "h36m17", "fps": 30}},
        "video": "https://studio.example/rehearsal/cam1.mp4",
        "video_offset_s": 12.5,
        "labels": {"source": "video"}
    });
    let (ingest, list) = tokio::task::spawn_blocking(move || {
        (
            http(h, "POST", "/v1/motions", Some(&body)),
            http(h, "GET", "/v1/motions", None),
        )
    })
    .await
    .unwrap();
    assert_eq!(ingest.0, 201, "{}", ingest.1);
    let kp_id = ingest.1["motion_id"].as_i64().unwrap();
    let motions = list.1["motions"].as_array().unwrap().clone();
    let mocap_id = motions
        .iter()
        .find(|r| {
            r["source_path"]
                .as_str()
                .unwrap()
                .ends_with("gJS_sFM_cAll_d02_mJS4_ch09.pkl")
        })
        .unwrap()["id"]
        .as_i64()
        .unwrap();
    let row = motions.iter().find(|r| r["id"] == kp_id).unwrap();
    assert_eq!(row["format"], "keypoints");
    assert_eq!(row["video"], "https://studio.example/rehearsal/cam1.mp4");
    assert_eq!(row["video_offset_s"], 12.5);

    // The stored keypoint motion reads back (its layout and frame rate were
    // stored with it), and a query from the mocap finds it with the video
    // time of the matched window.
    let q = json!({"motion": {"id": mocap_id}, "start_s": 10.0, "k": 5, "exact": true,
                   "embedding": "pose", "filters": {"source": "video"}});
    let q_all = json!({"motion": {"id": mocap_id}, "start_s": 10.0, "k": 1, "exact": true});
    let (got, hits, all) = tokio::task::spawn_blocking(move || {
        (
            http(h, "GET", &format!("/v1/motions/{kp_id}"), None),
            http(h, "POST", "/v1/query", Some(&q)),
            http(h, "POST", "/v1/query", Some(&q_all)),
        )
    })
    .await
    .unwrap();
    assert_eq!(got.0, 200, "{}", got.1);
    assert_eq!(
        got.1["motion"]["rotations"].as_array().unwrap().len(),
        kp.frames()
    );
    assert_eq!(hits.0, 200, "{}", hits.1);
    let hits = hits.1["hits"].as_array().unwrap().clone();
    let hit = &hits[0];
    assert_eq!(hit["motion_id"], kp_id, "{hits:?}");
    let start = hit["start_s"].as_f64().unwrap();
    assert!((start - 10.0).abs() <= 1.0, "{hit}");
    assert!(
        (hit["video_time_s"].as_f64().unwrap() - (12.5 + start)).abs() < 1e-9,
        "{hit}"
    );
    assert_eq!(hit["video"], "https://studio.example/rehearsal/cam1.mp4");
    // Mocap hits carry no video fields.
    let mocap_hit = &all.1["hits"][0];
    assert_eq!(mocap_hit["motion_id"], mocap_id, "{}", all.1);
    assert!(mocap_hit.get("video").is_none(), "{mocap_hit}");

    // gRPC: a MediaPipe JSON of the same take queries the mocap (filtered
    // by its corpus label; footage is searched by the pose embedding unless
    // the request names another); the take is the best hit, at the same
    // moment.
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{g}"))
        .await
        .unwrap();
    let mp = kpio::write_json(&noisy(&m, Layout::Mediapipe33, 12));
    let resp = client
        .query(pb::QueryRequest {
            motion: Some(pb::MotionSource {
                source: Some(pb::motion_source::Source::File(pb::UploadedFile {
                    name: "phone.json".into(),
                    content: mp.clone(),
                    keypoints: "mediapipe33".into(),
                    ..Default::default()
                })),
            }),
            start_s: 20.0,
            k: 5,
            exact: true,
            filters: [("corpus".to_string(), "aistpp".to_string())].into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let best = &resp.hits[0];
    assert_eq!(best.motion_id, mocap_id, "{:?}", resp.hits);
    assert!((best.start_s - 20.0).abs() <= 1.0, "{:?}", best);
    assert!(best.video.is_empty());

    // Bad input over both transports names the field.
    let bad = json!({"motion": {"file": {"name": "x.npy", "content_base64": b64(&mp),
                     "keypoints": "openpose25", "fps": 30}}});
    let no_fps = json!({"motion": {"file": {"name": "x.npy",
        "content_base64": b64(&kpio::write_npy(&kp)), "keypoints": "h36m17"}}, "k": 3});
    let offset_alone = json!({"motion": {"id": mocap_id}, "video_offset_s": 3.0});
    let (r1, r2, r3) = tokio::task::spawn_blocking(move || {
        (
            http(h, "POST", "/v1/query", Some(&bad)),
            http(h, "POST", "/v1/query", Some(&no_fps)),
            http(h, "POST", "/v1/motions", Some(&offset_alone)),
        )
    })
    .await
    .unwrap();
    assert_eq!(r1.0, 400, "{}", r1.1);
    assert_eq!(r1.1["error"]["field"], "motion.file.keypoints", "{}", r1.1);
    assert_eq!(r2.0, 400, "{}", r2.1);
    assert!(r2.1.to_string().contains("fps"), "{}", r2.1);
    assert_eq!(r3.0, 400, "{}", r3.1);
    assert_eq!(r3.1["error"]["field"], "video_offset_s", "{}", r3.1);
    let e = client
        .query(pb::QueryRequest {
            motion: Some(pb::MotionSource {
                source: Some(pb::motion_source::Source::File(pb::UploadedFile {
                    name: "phone.json".into(),
                    content: mp,
                    keypoints: "mediapipe33".into(),
                    up: "sideways".into(),
                    ..Default::default()
                })),
            }),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("motion.file.up"), "{}", e.message());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_store_without_pose_embeddings_gets_them_on_open() {
    use choreo::features::Embedding;
    use choreo::search::ingest::{ingest, IngestOptions};
    let Some(aist) = require("aistpp/motions") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let store = choreo::store::Store::open(&dir.path().join("old.db"))
        .await
        .unwrap();
    ingest(&store, &[aist], &IngestOptions::default(), &|_, _, _| {})
        .await
        .unwrap();
    let (_, windows) = store.counts().await.unwrap();
    assert!(windows > 50);
    let pose = store.embeddings(Embedding::Pose).await.unwrap();
    assert_eq!(pose.len(), windows);
    // A store written before the pose embedding existed: none stored.
    store
        .replace_embeddings(Embedding::Pose, &[], "pose", "{}", 0)
        .await
        .unwrap();
    assert_eq!(store.count_embeddings(Embedding::Pose).await.unwrap(), 0);
    let searcher = choreo::search::Searcher::open(store.clone(), Default::default())
        .await
        .unwrap();
    drop(searcher);
    let again = store.embeddings(Embedding::Pose).await.unwrap();
    assert_eq!(again.len(), windows);
    // The same vectors as at ingest.
    let before: std::collections::HashMap<i64, Vec<f32>> = pose.into_iter().collect();
    for (id, v) in again {
        assert_eq!(before[&id], v, "window {id}");
    }
}
