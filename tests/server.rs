//! The server end to end: started on port 0 over a store of the real AIST++
//! samples (skipped with a reason without the data; failing instead under
//! `CHOREO_REQUIRE_DATA=1`), called over REST and gRPC, including the error
//! paths. REST and gRPC must give identical results for the same request.

use base64::Engine;
use choreo::api::grpc::pb;
use choreo::data::require;
use choreo::server::{start, ServeConfig};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::path::PathBuf;

/// One HTTP/1.1 request over a fresh connection; returns (status, JSON body).
fn http(addr: SocketAddr, method: &str, path: &str, body: Option<&Value>) -> (u16, Value) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    let b = body.map(|v| v.to_string()).unwrap_or_default();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{b}",
        b.len()
    )
    .unwrap();
    let mut out = Vec::new();
    s.read_to_end(&mut out).unwrap();
    let text = String::from_utf8_lossy(&out).to_string();
    let status: u16 = text[9..12].parse().unwrap();
    let (head, rest) = text.split_once("\r\n\r\n").unwrap();
    // Chunked bodies: join the chunks.
    let body = if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        let mut out = String::new();
        let mut r = rest;
        loop {
            let (len, tail) = r.split_once("\r\n").unwrap();
            let n = usize::from_str_radix(len.trim(), 16).unwrap();
            if n == 0 {
                break;
            }
            out.push_str(&tail[..n]);
            r = &tail[n + 2..];
        }
        out
    } else {
        rest.to_string()
    };
    (
        status,
        serde_json::from_str(&body).unwrap_or(Value::String(body)),
    )
}

fn config(dir: &std::path::Path, ingest: Vec<PathBuf>) -> ServeConfig {
    ServeConfig {
        data_dir: dir.to_path_buf(),
        bind: "127.0.0.1".into(),
        http_port: 0,
        grpc_port: 0,
        max_body_mb: 64,
        workers: 2,
        ingest,
        model: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/default"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rest_and_grpc_agree_on_real_data_and_report_errors() {
    let Some(aist) = require("aistpp/motions") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), vec![aist.clone()]))
        .await
        .unwrap();
    let (h, g) = (running.http, running.grpc);
    let file = aist.join("gJS_sFM_cAll_d02_mJS4_ch09.pkl");
    let bytes = std::fs::read(&file).unwrap();
    let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);

    eprintln!("started: REST {h}, gRPC {g}");
    // Health and the motion list.
    let hh = tokio::task::spawn_blocking(move || {
        let (s, _) = http(h, "GET", "/healthz", None);
        let (s2, list) = http(h, "GET", "/v1/motions", None);
        (s, s2, list)
    })
    .await
    .unwrap();
    assert_eq!((hh.0, hh.1), (200, 200));
    assert_eq!(hh.2["motions"].as_array().unwrap().len(), 4);

    eprintln!("health ok");
    // Query over REST and gRPC with the same request.
    let body = json!({"motion": {"file": {"name": "gJS_sFM_cAll_d02_mJS4_ch09.pkl", "content_base64": b64}},
                      "start_s": 3.0, "k": 5, "embedding": "dct", "filters": {"genre": "JS"}});
    let (status, rest) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/query", Some(&body)))
            .await
            .unwrap();
    assert_eq!(status, 200, "{rest}");
    let rest_hits = rest["hits"].as_array().unwrap().clone();
    eprintln!("REST query ok");
    assert!(!rest_hits.is_empty());
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{g}"))
        .await
        .unwrap();
    let source = |name: &str, content: Vec<u8>| pb::MotionSource {
        source: Some(pb::motion_source::Source::File(pb::UploadedFile {
            name: name.into(),
            content,
        })),
    };
    let resp = client
        .query(pb::QueryRequest {
            motion: Some(source("gJS_sFM_cAll_d02_mJS4_ch09.pkl", bytes.clone())),
            start_s: 3.0,
            k: 5,
            embedding: "dct".into(),
            filters: [("genre".to_string(), "JS".to_string())]
                .into_iter()
                .collect(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(resp.hits.len(), rest_hits.len());
    for (a, b) in resp.hits.iter().zip(&rest_hits) {
        assert_eq!(a.motion_id, b["motion_id"].as_i64().unwrap());
        assert_eq!(a.start_frame, b["start_frame"].as_i64().unwrap());
        assert!((a.score as f64 - b["score"].as_f64().unwrap()).abs() < 1e-6);
        assert_eq!(a.labels.get("genre").map(String::as_str), Some("JS"));
    }

    eprintln!("gRPC query ok");
    // Keyframes over both: the same keyframes and error.
    let body = json!({"motion": {"file": {"name": "a.pkl", "content_base64": base64::engine::general_purpose::STANDARD.encode(&bytes)}},
                      "count": 12, "select": "dp"});
    let (status, rest) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/keyframes", Some(&body)))
            .await
            .unwrap();
    assert_eq!(status, 200, "{rest}");
    eprintln!("REST keyframes ok");
    let k = client
        .keyframes(pb::KeyframesRequest {
            motion: Some(source("a.pkl", bytes.clone())),
            count: 12,
            select: "dp".into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let rest_keys: Vec<u32> = rest["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as u32)
        .collect();
    assert_eq!(k.keyframes, rest_keys);
    eprintln!("gRPC keyframes ok");
    assert!((k.mse - rest["mse"].as_f64().unwrap()).abs() < 1e-12);

    // Errors name the field, with the right code on each transport.
    let bad = json!({"motion": {"motion": {"fps": 60, "skeleton": "smpl24", "rotations": [[[0.0, 0.0, 0.0]]], "translation": [[0, 0, 0]]}}, "k": 3});
    let (status, err) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/query", Some(&bad)))
            .await
            .unwrap();
    assert_eq!(status, 400, "{err}");
    assert_eq!(err["error"]["field"], "motion.motion.rotations", "{err}");
    let (status, err) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/query", Some(&json!({"k": 3}))))
            .await
            .unwrap();
    assert_eq!(
        (status, err["error"]["field"].as_str()),
        (400, Some("motion"))
    );
    let (status, err) = tokio::task::spawn_blocking(move || {
        let mut s = std::net::TcpStream::connect(h).unwrap();
        write!(s, "POST /v1/query HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: 4\r\n\r\n{{bad").unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        (out[9..12].parse::<u16>().unwrap(), out)
    })
    .await
    .unwrap();
    assert_eq!(status, 400, "{err}");
    let e = client
        .keyframes(pb::KeyframesRequest {
            motion: Some(source("a.pkl", bytes.clone())),
            count: 1,
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("count"), "{}", e.message());
    let e = client
        .query(pb::QueryRequest {
            motion: Some(source("junk.bvh", b"HIERARCHY nope".to_vec())),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{}", e.message());

    running.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_worker_pool_says_busy() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path(), vec![]);
    cfg.workers = 1;
    let running = start(&cfg).await.unwrap();
    let h = running.http;
    // A long interpolation holds the only permit; a second heavy request
    // is refused with 429 at once.
    let sine = |hz: f64| -> Value {
        let frames = 600;
        let rot: Vec<Vec<[f64; 3]>> = (0..frames)
            .map(|f| {
                let mut r = vec![[0.0; 3]; 24];
                r[18] = [0.0, 0.0, (hz * f as f64 / 60.0).sin()];
                r
            })
            .collect();
        json!({"motion": {"fps": 60.0, "skeleton": "smpl24", "rotations": rot, "translation": vec![[0.0, 0.9, 0.0]; frames]}})
    };
    let long = json!({"input": sine(1.0), "target": sine(3.0), "objective": "stft", "steps": 3000});
    let first =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/interpolate", Some(&long)));
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let quick = json!({"motion": sine(2.0), "cutoff": 8});
    let (status, err) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/lowpass", Some(&quick)))
            .await
            .unwrap();
    assert_eq!(status, 429, "{err}");
    assert_eq!(err["error"]["code"], "resource_exhausted");
    let (status, done) = first.await.unwrap();
    assert_eq!(status, 200, "{done}");
    assert_eq!(done["steps"], 3000);
    running.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn generate_stream_duet_and_classify_with_the_bundled_model() {
    let Some(aist) = require("aistpp/motions") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), vec![])).await.unwrap();
    let (h, g) = (running.http, running.grpc);
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{g}"))
        .await
        .unwrap();
    // Standard gRPC health says the service is serving.
    let channel = tonic::transport::Channel::from_shared(format!("http://{g}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel);
    let st = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: "choreo.v1.Choreo".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        st.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    let file = aist.join("gBR_sBM_cAll_d04_mBR2_ch08.pkl");
    let bytes = std::fs::read(&file).unwrap();
    let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);

    // One-shot generation with a joint prompt, REST and gRPC, same request.
    let req = json!({
        "labels": {"genre": "BR"},
        "frames": 24,
        "prompt": {"file": {"name": "gBR_sBM_cAll_d04_mBR2_ch08.pkl", "content_base64": b64}},
        "prompt_joints": ["pelvis", "right_shoulder", "right_elbow"],
        "sampling": {"temperature": 0.9, "top_k": 40, "top_p": 0.95, "seed": 7}
    });
    let (status, rest) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/generate", Some(&req)))
            .await
            .unwrap();
    assert_eq!(status, 200, "{rest}");
    let out = &rest["output"];
    assert_eq!(out["translation"].as_array().unwrap().len(), 24);
    assert_eq!(out["skeleton"], "smpl13");
    let upload = pb::MotionSource {
        source: Some(pb::motion_source::Source::File(pb::UploadedFile {
            name: "gBR_sBM_cAll_d04_mBR2_ch08.pkl".into(),
            content: bytes.clone(),
        })),
    };
    let greq = pb::GenerateRequest {
        labels: [("genre".to_string(), "BR".to_string())]
            .into_iter()
            .collect(),
        frames: 24,
        prompt: Some(upload.clone()),
        prompt_joints: vec![
            "pelvis".into(),
            "right_shoulder".into(),
            "right_elbow".into(),
        ],
        seed_motion: None,
        sampling: Some(pb::Sampling {
            temperature: 0.9,
            top_k: 40,
            top_p: 0.95,
            seed: 7,
        }),
    };
    let one = client.generate(greq.clone()).await.unwrap().into_inner();
    let m = one.output.unwrap();
    let rest_rot: Vec<f64> = out["rotations"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|f| {
            f.as_array()
                .unwrap()
                .iter()
                .flat_map(|j| j.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        })
        .collect();
    // JSON carries decimal text, so the two agree to the last printed digit.
    assert_eq!(m.rotations.len(), rest_rot.len());
    let worst = m
        .rotations
        .iter()
        .zip(&rest_rot)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-12,
        "REST and gRPC generate the same frames (worst {worst})"
    );
    assert!(m.rotations.iter().all(|x| x.is_finite()));

    // Streaming gives the one-shot frames, one message each.
    let mut stream = client.generate_stream(greq).await.unwrap().into_inner();
    let mut frames = Vec::new();
    while let Some(f) = stream.message().await.unwrap() {
        frames.push(f);
    }
    assert_eq!(frames.len(), 24);
    let streamed: Vec<f64> = frames.iter().flat_map(|f| f.rotations.clone()).collect();
    assert_eq!(streamed, m.rotations, "stream equals one-shot");
    let streamed_t: Vec<f64> = frames.iter().flat_map(|f| f.translation.clone()).collect();
    assert_eq!(streamed_t, m.translation);

    // A duet: the performer's right arm in, full bodies out, frame for frame.
    let perf = choreo::motion::io::read_path(&file, &Default::default())
        .unwrap()
        .motion;
    let perf = choreo::features::as_smpl13(&perf)
        .unwrap()
        .resample(20.0)
        .unwrap();
    let n = 10;
    let mut msgs = Vec::new();
    for f in 0..n {
        msgs.push(pb::DuetRequest {
            labels: if f == 0 {
                [("genre".to_string(), "BR".to_string())]
                    .into_iter()
                    .collect()
            } else {
                Default::default()
            },
            prompt_joints: if f == 0 {
                vec!["right_shoulder".into(), "right_elbow".into()]
            } else {
                vec![]
            },
            sampling: None,
            frame: Some(pb::Motion {
                fps: 20.0,
                skeleton: "smpl13".into(),
                rotations: perf
                    .frame_rotations(f)
                    .iter()
                    .flat_map(|r| r.iter().copied())
                    .collect(),
                translation: perf.trans[f].to_vec(),
                ..Default::default()
            }),
        });
    }
    let mut duet = client
        .duet(tokio_stream::iter(msgs))
        .await
        .unwrap()
        .into_inner();
    let mut got = 0;
    while let Some(f) = duet.message().await.unwrap() {
        assert_eq!(f.index as usize, got);
        assert_eq!(f.rotations.len(), 39);
        got += 1;
    }
    assert_eq!(got, n);

    // Classification over both transports.
    let body = json!({"motion": {"file": {"name": "gBR_sBM_cAll_d04_mBR2_ch08.pkl",
        "content_base64": base64::engine::general_purpose::STANDARD.encode(&bytes)}}});
    let (status, rc) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/classify", Some(&body)))
            .await
            .unwrap();
    assert_eq!(status, 200, "{rc}");
    let gc = client
        .classify(pb::ClassifyRequest {
            motion: Some(upload),
        })
        .await
        .unwrap()
        .into_inner();
    let kinds = rc["classes"].as_array().unwrap();
    assert_eq!(kinds.len(), gc.classes.len());
    for (r, g) in kinds.iter().zip(&gc.classes) {
        assert_eq!(r["kind"], g.kind.as_str());
        assert_eq!(r["label"], g.label.as_str());
        let total: f64 = g.scores.iter().map(|s| s.probability).sum();
        assert!((total - 1.0).abs() < 1e-6);
    }

    // Error paths name the field.
    let bad = json!({"labels": {"genre": "XX"}, "frames": 5});
    let (status, err) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/generate", Some(&bad)))
            .await
            .unwrap();
    assert_eq!(status, 400, "{err}");
    assert!(
        err["error"]["field"].as_str().unwrap().contains("labels"),
        "{err}"
    );
    let bad = json!({"frames": 100000});
    let (status, err) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/generate", Some(&bad)))
            .await
            .unwrap();
    assert_eq!(
        (status, err["error"]["field"].as_str()),
        (400, Some("frames")),
        "{err}"
    );
    let e = client
        .generate(pb::GenerateRequest {
            prompt_joints: vec!["tail".into()],
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);

    // Prometheus metrics count both transports by route and outcome.
    let (status, _) = tokio::task::spawn_blocking(move || http(h, "GET", "/healthz", None))
        .await
        .unwrap();
    assert_eq!(status, 200);
    let metrics = tokio::task::spawn_blocking(move || {
        let mut s = std::net::TcpStream::connect(h).unwrap();
        write!(
            s,
            "GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        out
    })
    .await
    .unwrap();
    for want in [
        "choreo_requests_total{transport=\"http\",route=\"/v1/generate\",code=\"200\"} 1",
        "choreo_requests_total{transport=\"http\",route=\"/v1/generate\",code=\"400\"} 2",
        "choreo_requests_total{transport=\"grpc\",route=\"/choreo.v1.Choreo/Generate\",code=\"0\"} 1",
        "choreo_request_seconds_bucket{transport=\"http\",route=\"/v1/classify\",code=\"200\",le=\"+Inf\"} 1",
    ] {
        assert!(metrics.contains(want), "missing {want} in\n{metrics}");
    }
    running.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_model_generate_is_unavailable() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path(), vec![]);
    cfg.model = dir.path().join("no-model-here");
    let running = start(&cfg).await.unwrap();
    let h = running.http;
    let (status, err) =
        tokio::task::spawn_blocking(move || http(h, "POST", "/v1/generate", Some(&json!({}))))
            .await
            .unwrap();
    assert_eq!(status, 503, "{err}");
    assert_eq!(err["error"]["code"], "unavailable");
    running.shutdown().await.unwrap();
}
