//! What browsers need from the server: CORS (preflight answered, only the
//! configured origins allowed) and the WebSocket streams for generation and
//! the duet, including their bad-input paths. Uses the bundled model; no
//! data files needed.

use choreo::server::{start, ServeConfig};
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::SocketAddr;
use tokio_tungstenite::tungstenite::Message;

mod support;

fn config(dir: &std::path::Path, cors: &[&str]) -> ServeConfig {
    ServeConfig {
        token: Some("t0ken".into()),
        cors_origins: cors.iter().map(|s| s.to_string()).collect(),
        ..support::serve_config(dir)
    }
}

/// A raw HTTP/1.1 exchange: (status, lower-cased headers, body).
fn raw(addr: SocketAddr, request: &str) -> (u16, Vec<(String, String)>, String) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.write_all(request.as_bytes()).unwrap();
    let mut out = Vec::new();
    s.read_to_end(&mut out).unwrap();
    let text = String::from_utf8_lossy(&out).to_string();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    (status, headers, body.to_string())
}

fn header<'a>(h: &'a [(String, String)], name: &str) -> Option<&'a str> {
    h.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
}

fn get_with_origin(addr: SocketAddr, origin: &str) -> (u16, Vec<(String, String)>, String) {
    raw(
        addr,
        &format!(
            "GET /healthz HTTP/1.1\r\nHost: x\r\nOrigin: {origin}\r\nConnection: close\r\n\r\n"
        ),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cors_allows_only_the_configured_origins() {
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), &["http://studio.test"]))
        .await
        .unwrap();
    let h = running.http;
    let (pre, ok, evil, write) = tokio::task::spawn_blocking(move || {
        let pre = raw(
            h,
            "OPTIONS /v1/query HTTP/1.1\r\nHost: x\r\nOrigin: http://studio.test\r\n\
             Access-Control-Request-Method: POST\r\n\
             Access-Control-Request-Headers: content-type, authorization\r\nConnection: close\r\n\r\n",
        );
        let ok = get_with_origin(h, "http://studio.test");
        let evil = get_with_origin(h, "http://evil.test");
        // A cross-origin write without the token is still refused.
        let write = raw(
            h,
            "DELETE /v1/motions/1 HTTP/1.1\r\nHost: x\r\nOrigin: http://studio.test\r\nConnection: close\r\nContent-Length: 0\r\n\r\n",
        );
        (pre, ok, evil, write)
    })
    .await
    .unwrap();
    assert_eq!(pre.0, 200, "{pre:?}");
    assert_eq!(
        header(&pre.1, "access-control-allow-origin"),
        Some("http://studio.test")
    );
    let methods = header(&pre.1, "access-control-allow-methods").unwrap_or("");
    assert!(
        methods.contains("POST") && methods.contains("DELETE"),
        "{methods}"
    );
    let allowed = header(&pre.1, "access-control-allow-headers")
        .unwrap_or("")
        .to_ascii_lowercase();
    assert!(allowed.contains("authorization") && allowed.contains("content-type"));
    assert_eq!(ok.0, 200);
    assert_eq!(
        header(&ok.1, "access-control-allow-origin"),
        Some("http://studio.test")
    );
    assert_eq!(evil.0, 200);
    assert_eq!(header(&evil.1, "access-control-allow-origin"), None);
    assert_eq!(write.0, 401, "{write:?}");
    assert_eq!(
        header(&write.1, "access-control-allow-origin"),
        Some("http://studio.test"),
        "the browser must be able to read the error"
    );
    running.shutdown().await.unwrap();

    // Without --cors-origin, no cross-origin reads.
    let dir2 = tempfile::tempdir().unwrap();
    let closed = start(&config(dir2.path(), &[])).await.unwrap();
    let h2 = closed.http;
    let r = tokio::task::spawn_blocking(move || get_with_origin(h2, "http://studio.test"))
        .await
        .unwrap();
    assert_eq!(header(&r.1, "access-control-allow-origin"), None);
    closed.shutdown().await.unwrap();

    // A bad origin stops start-up, named.
    let dir3 = tempfile::tempdir().unwrap();
    let err = start(&config(dir3.path(), &["studio.test/path"]))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("--cors-origin"), "{err}");
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(addr: SocketAddr, path: &str) -> Ws {
    tokio_tungstenite::connect_async(format!("ws://{addr}{path}"))
        .await
        .unwrap()
        .0
}

/// The next JSON message; `None` once the server closed.
async fn recv(ws: &mut Ws) -> Option<Value> {
    loop {
        let m = tokio::time::timeout(std::time::Duration::from_secs(60), ws.next())
            .await
            .expect("the server answers within a minute")?;
        match m.ok()? {
            Message::Text(t) => return Some(serde_json::from_str(t.as_str()).unwrap()),
            Message::Close(_) => return None,
            _ => continue,
        }
    }
}

async fn rest_generate(addr: SocketAddr, body: Value) -> (u16, Value) {
    tokio::task::spawn_blocking(move || {
        let b = body.to_string();
        let (status, _, text) = raw(
            addr,
            &format!(
                "POST /v1/generate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{b}",
                b.len()
            ),
        );
        (status, serde_json::from_str(&text).unwrap_or(Value::Null))
    })
    .await
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn websocket_generate_streams_what_rest_returns_and_stops_with_the_client() {
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), &[])).await.unwrap();
    let h = running.http;
    let request = json!({"frames": 24, "sampling": {"temperature": 0.9, "top_p": 0.95, "seed": 7}});
    let mut ws = connect(h, "/v1/generate/ws").await;
    ws.send(Message::Text(request.to_string().into()))
        .await
        .unwrap();
    let start_msg = recv(&mut ws).await.unwrap();
    assert_eq!(start_msg["start"]["skeleton"], "smpl13", "{start_msg}");
    let mut frames = Vec::new();
    let end = loop {
        let m = recv(&mut ws)
            .await
            .expect("an end message before the close");
        if m.get("frame").is_some() {
            frames.push(m["frame"].clone());
        } else {
            break m;
        }
    };
    assert_eq!(end["end"]["frames"], 24, "{end}");
    assert_eq!(frames.len(), 24);
    assert!(recv(&mut ws).await.is_none(), "closed after the end");
    // The same request over REST: the same frames.
    let (status, rest) = rest_generate(h, request).await;
    assert_eq!(status, 200, "{rest}");
    let out = &rest["output"];
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f["index"], i);
        assert_eq!(f["rotations"].as_array().unwrap().len(), 13);
        for (a, b) in f["rotations"]
            .as_array()
            .unwrap()
            .iter()
            .zip(out["rotations"][i].as_array().unwrap())
        {
            for k in 0..3 {
                let (x, y) = (a[k].as_f64().unwrap(), b[k].as_f64().unwrap());
                assert!((x - y).abs() < 1e-9, "frame {i}: {x} vs {y}");
            }
        }
    }

    // With labels, the stream starts from the style exemplar the one-shot
    // call names, and with the same sampling (defaults filled in).
    let labelled = json!({"labels": {"style": "angry"}, "frames": 2, "sampling": {"seed": 3}});
    let mut ws = connect(h, "/v1/generate/ws").await;
    ws.send(Message::Text(labelled.to_string().into()))
        .await
        .unwrap();
    let start_msg = recv(&mut ws).await.unwrap();
    let (status, rest) = rest_generate(h, labelled).await;
    assert_eq!(status, 200, "{rest}");
    assert!(rest["exemplar"]["source"].is_string(), "{rest}");
    assert_eq!(
        start_msg["start"]["exemplar"], rest["exemplar"],
        "{start_msg}"
    );
    assert_eq!(
        start_msg["start"]["sampling"], rest["sampling"],
        "{start_msg}"
    );
    assert_eq!(rest["sampling"]["max_jump"], 12, "{rest}");
    assert_eq!(rest["sampling"]["posture"], 1.5, "{rest}");
    drop(ws);

    // Not JSON: an error naming the body, then the close.
    let mut bad = connect(h, "/v1/generate/ws").await;
    bad.send(Message::Text("{frames: 3".into())).await.unwrap();
    let e = recv(&mut bad).await.unwrap();
    assert_eq!(e["error"]["code"], "invalid_argument", "{e}");
    assert!(recv(&mut bad).await.is_none());
    // A misspelt field is named.
    let mut typo = connect(h, "/v1/generate/ws").await;
    typo.send(Message::Text(r#"{"frame": 3}"#.into()))
        .await
        .unwrap();
    let e = recv(&mut typo).await.unwrap();
    assert_eq!(e["error"]["field"], "frame", "{e}");

    // A client that leaves mid-stream frees its worker: two generations
    // then run at once (2 workers) well before the long one would end.
    let mut gone = connect(h, "/v1/generate/ws").await;
    gone.send(Message::Text(json!({"frames": 2400}).to_string().into()))
        .await
        .unwrap();
    recv(&mut gone).await.unwrap();
    recv(&mut gone).await.unwrap();
    drop(gone);
    let t0 = std::time::Instant::now();
    loop {
        let short = json!({"frames": 2});
        let (a, b) = tokio::join!(rest_generate(h, short.clone()), rest_generate(h, short));
        if a.0 == 200 && b.0 == 200 {
            break;
        }
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(8),
            "the abandoned stream still holds its worker ({} / {})",
            a.0,
            b.0
        );
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    running.shutdown().await.unwrap();
}

fn smpl13_frame(lift: f64) -> Value {
    json!({"fps": 20.0, "skeleton": "smpl13",
           "rotations": [vec![[0.0, 0.0, lift]; 13]],
           "translation": [[0.0, 0.9, 0.0]]})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn websocket_duet_answers_frame_for_frame_and_refuses_a_wrong_frame() {
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), &[])).await.unwrap();
    let mut ws = connect(running.http, "/v1/duet/ws").await;
    let setup = json!({"labels": {}, "prompt_joints": ["pelvis", "left_shoulder"],
                       "sampling": {"seed": 3}, "frame": smpl13_frame(0.0)});
    ws.send(Message::Text(setup.to_string().into()))
        .await
        .unwrap();
    let first = recv(&mut ws).await.unwrap();
    assert_eq!(first["frame"]["index"], 0, "{first}");
    for i in 1..5 {
        let m = json!({"frame": smpl13_frame(0.1 * i as f64)});
        ws.send(Message::Text(m.to_string().into())).await.unwrap();
        let r = recv(&mut ws).await.unwrap();
        assert_eq!(r["frame"]["index"], i, "{r}");
        assert_eq!(r["frame"]["rotations"].as_array().unwrap().len(), 13);
    }
    // Twelve joints for a 13-joint skeleton: an error, then the close.
    let mut wrong = smpl13_frame(0.0);
    wrong["rotations"] = json!([vec![[0.0, 0.0, 0.0]; 12]]);
    ws.send(Message::Text(json!({"frame": wrong}).to_string().into()))
        .await
        .unwrap();
    let e = recv(&mut ws).await.unwrap();
    assert_eq!(e["error"]["code"], "invalid_argument", "{e}");
    assert!(
        e["error"]["field"].as_str().unwrap().starts_with("frame"),
        "{e}"
    );
    assert!(recv(&mut ws).await.is_none());

    // A client that has full SMPL-24 frames sends them as they are: the
    // server folds them onto the model's 13 joints.
    let mut full = connect(running.http, "/v1/duet/ws").await;
    let smpl24 = |lift: f64| {
        json!({"fps": 20.0, "skeleton": "smpl24",
               "rotations": [vec![[0.0, 0.0, lift]; 24]],
               "translation": [[0.0, 0.9, 0.0]]})
    };
    let setup = json!({"prompt_joints": ["pelvis"], "frame": smpl24(0.0)});
    full.send(Message::Text(setup.to_string().into()))
        .await
        .unwrap();
    assert_eq!(recv(&mut full).await.unwrap()["frame"]["index"], 0);
    full.send(Message::Text(
        json!({"frame": smpl24(0.2)}).to_string().into(),
    ))
    .await
    .unwrap();
    let r = recv(&mut full).await.unwrap();
    assert_eq!(r["frame"]["index"], 1, "{r}");
    assert_eq!(r["frame"]["rotations"].as_array().unwrap().len(), 13);
    running.shutdown().await.unwrap();
}

/// `GET /v1/motions/{id}/glb` gives a binary glTF of the stored motion
/// (its joints and frames; scripts/check_gltf.py checks the pose against
/// choreo's FK in an independent reader); an unknown id is 404.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stored_motion_exports_as_glb() {
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), &[])).await.unwrap();
    let h = running.http;
    let frames = 12;
    let body = json!({"motion": {"motion": {
        "fps": 30.0, "skeleton": "smpl24",
        "rotations": (0..frames).map(|f| vec![[0.0, 0.02 * f as f64, 0.0]; 24]).collect::<Vec<_>>(),
        "translation": vec![[0.0, 0.9, 0.0]; frames]}}})
    .to_string();
    let (glb_status, glb_headers, glb_body, missing) = tokio::task::spawn_blocking(move || {
        let (status, _, text) = raw(
            h,
            &format!(
                "POST /v1/motions HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer t0ken\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
                body.len()
            ),
        );
        assert_eq!(status, 201, "{text}");
        let id = serde_json::from_str::<Value>(&text).unwrap()["motion_id"]
            .as_i64()
            .unwrap();
        let mut s = std::net::TcpStream::connect(h).unwrap();
        write!(
            s,
            "GET /v1/motions/{id}/glb HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .unwrap();
        let mut out = Vec::new();
        s.read_to_end(&mut out).unwrap();
        let split = out.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        let head = String::from_utf8_lossy(&out[..split]).to_ascii_lowercase();
        let missing = raw(
            h,
            "GET /v1/motions/999999/glb HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
        );
        (head.clone(), head, out[split + 4..].to_vec(), missing.0)
    })
    .await
    .unwrap();
    assert!(glb_status.starts_with("http/1.1 200"), "{glb_status}");
    assert!(glb_headers.contains("content-type: model/gltf-binary"));
    assert_eq!(&glb_body[..4], b"glTF");
    let jl = u32::from_le_bytes(glb_body[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&glb_body[20..20 + jl]).unwrap();
    assert_eq!(doc["skins"][0]["joints"].as_array().unwrap().len(), 24);
    let times = doc["animations"][0]["samplers"][0]["input"]
        .as_u64()
        .unwrap() as usize;
    assert_eq!(doc["accessors"][times]["count"], frames);
    assert_eq!(missing, 404);
    running.shutdown().await.unwrap();
}

/// Every answer carries `x-request-id`: the caller's when it sent a usable
/// one, a new one otherwise (REST and gRPC), so a log line can be found
/// from a client's report.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn request_ids_are_echoed_over_both_transports() {
    use choreo::api::grpc::pb;
    let dir = tempfile::tempdir().unwrap();
    let running = start(&config(dir.path(), &[])).await.unwrap();
    let h = running.http;
    let (given, fresh, other, nf) = tokio::task::spawn_blocking(move || {
        let get = |extra: &str, path: &str| {
            raw(
                h,
                &format!("GET {path} HTTP/1.1\r\nHost: x\r\n{extra}Connection: close\r\n\r\n"),
            )
        };
        (
            get("X-Request-Id: studio-42\r\n", "/healthz"),
            get("", "/healthz"),
            get("", "/healthz"),
            get("x-request-id: bad id with spaces\r\n", "/v1/nowhere"),
        )
    })
    .await
    .unwrap();
    assert_eq!(header(&given.1, "x-request-id"), Some("studio-42"));
    let (a, b) = (
        header(&fresh.1, "x-request-id").unwrap(),
        header(&other.1, "x-request-id").unwrap(),
    );
    assert!(
        a.len() == 16 && a.bytes().all(|c| c.is_ascii_hexdigit()),
        "{a}"
    );
    assert_ne!(a, b);
    assert_eq!(nf.0, 404);
    let own = header(&nf.1, "x-request-id").unwrap();
    assert_ne!(own, "bad id with spaces");
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{}", running.grpc))
        .await
        .unwrap();
    let mut req = tonic::Request::new(pb::ListMotionsRequest {});
    req.metadata_mut()
        .insert("x-request-id", "rig-7".parse().unwrap());
    let resp = client.list_motions(req).await.unwrap();
    assert_eq!(resp.metadata().get("x-request-id").unwrap(), "rig-7");
    let resp = client
        .list_motions(pb::ListMotionsRequest {})
        .await
        .unwrap();
    assert_eq!(
        resp.metadata().get("x-request-id").unwrap().len(),
        16,
        "a fresh id"
    );
    running.shutdown().await.unwrap();
}

/// A body over `--max-body-mb` is 413 with the error body (code
/// resource_exhausted), not a 400.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_body_is_413() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path(), &[]);
    cfg.max_body_mb = 1;
    let running = start(&cfg).await.unwrap();
    let h = running.http;
    let (status, _, text) = tokio::task::spawn_blocking(move || {
        let big = format!(
            r#"{{"motion": {{"file": {{"name": "x.bvh", "content_base64": "{}"}}}}}}"#,
            "A".repeat(1_500_000)
        );
        raw(
            h,
            &format!(
                "POST /v1/query HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{big}",
                big.len()
            ),
        )
    })
    .await
    .unwrap();
    assert_eq!(status, 413, "{text}");
    let v: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["error"]["code"], "resource_exhausted", "{v}");
    running.shutdown().await.unwrap();
}
