//! Who may do what, over both transports: scoped tokens from a token file,
//! reads closed unless `--public-read`, a revoked token refused at once, the
//! audit trail (token names and request ids, never secrets), per-client
//! rate limits with Retry-After, and start-up refusals for bad settings.
//! Runs on an empty store (no data needed): writes are inline motions.

use choreo::api::grpc::pb;
use choreo::server::{start, ServeConfig};
use choreo::service::auth::hash_token;
use serde_json::{json, Value};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use support::header;

mod support;

/// One request; returns (status, lower-cased head, JSON body).
fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    body: Option<&Value>,
    token: Option<&str>,
) -> (u16, String, Value) {
    support::exchange(addr, method, path, body, token).unwrap()
}

fn config(dir: &Path, tokens: Option<PathBuf>, public_read: bool, rate: f64) -> ServeConfig {
    ServeConfig {
        model: PathBuf::from("/nonexistent-model"),
        inbetweener: PathBuf::from("/nonexistent-inbetweener"),
        tokens,
        public_read,
        rate_limit: rate,
        rate_burst: rate,
        ..support::serve_config(&dir.join("data"))
    }
}

fn inline_motion(name: &str, phase: f64) -> Value {
    let frames = 140;
    let rotations: Vec<Vec<[f64; 3]>> = (0..frames)
        .map(|f| {
            (0..24)
                .map(|j| [0.3 * ((f as f64) * 0.1 + phase + j as f64).sin(), 0.0, 0.1])
                .collect()
        })
        .collect();
    json!({"name": name, "fps": 60.0, "skeleton": "smpl24", "rotations": rotations,
           "translation": vec![[0.0, 0.9, 0.0]; frames]})
}

fn tokens_file(dir: &Path) -> PathBuf {
    let p = dir.join("tokens");
    std::fs::write(
        &p,
        format!(
            "# name scopes hash\nreader read {}\nwriter read,write {}\nops read,write,admin {}\n",
            hash_token("reader-secret"),
            hash_token("writer-secret"),
            hash_token("ops-secret")
        ),
    )
    .unwrap();
    p
}

fn grpc_req<T>(msg: T, token: Option<&str>) -> tonic::Request<T> {
    let mut r = tonic::Request::new(msg);
    if let Some(t) = token {
        r.metadata_mut()
            .insert("authorization", format!("Bearer {t}").parse().unwrap());
    }
    r
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scoped_tokens_revocation_and_the_audit_trail_over_both_transports() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = tokens_file(dir.path());
    let running = start(&config(dir.path(), Some(tokens.clone()), false, 0.0))
        .await
        .unwrap();
    let (h, g) = (running.http, running.grpc);
    let m =
        json!({"motion": {"motion": inline_motion("take_a", 0.0)}, "labels": {"session": "s1"}});
    let tf = tokens.clone();
    let (anon, read, read_write, written, del_read, audit_writer, audit_ops, health) =
        tokio::task::spawn_blocking(move || {
            let anon = http(h, "GET", "/v1/motions", None, None);
            let read = http(h, "GET", "/v1/motions", None, Some("reader-secret"));
            let read_write = http(h, "POST", "/v1/motions", Some(&m), Some("reader-secret"));
            let written = http(h, "POST", "/v1/motions", Some(&m), Some("writer-secret"));
            let id = written.2["motion_id"].as_i64().unwrap();
            let del_read = http(
                h,
                "DELETE",
                &format!("/v1/motions/{id}"),
                None,
                Some("reader-secret"),
            );
            let audit_writer = http(h, "GET", "/v1/audit", None, Some("writer-secret"));
            let audit_ops = http(h, "GET", "/v1/audit?limit=10", None, Some("ops-secret"));
            let health = http(h, "GET", "/healthz", None, None);
            (
                anon,
                read,
                read_write,
                written,
                del_read,
                audit_writer,
                audit_ops,
                health,
            )
        })
        .await
        .unwrap();
    // Reads are closed without --public-read; liveness stays open.
    assert_eq!(anon.0, 401, "{}", anon.2);
    assert_eq!(anon.2["error"]["code"], "unauthenticated");
    assert_eq!(health.0, 200);
    assert_eq!(read.0, 200, "{}", read.2);
    // A read token cannot write.
    assert_eq!(read_write.0, 403, "{}", read_write.2);
    assert_eq!(read_write.2["error"]["code"], "permission_denied");
    assert_eq!(written.0, 201, "{}", written.2);
    assert_eq!(del_read.0, 403, "{}", del_read.2);
    // The audit trail is admin's: the write with the token's name and the
    // request id the answer carried, and no secret anywhere.
    assert_eq!(audit_writer.0, 403);
    assert_eq!(audit_ops.0, 200, "{}", audit_ops.2);
    let entries = audit_ops.2["entries"].as_array().unwrap();
    assert_eq!(entries.len(), 1, "{entries:?}");
    assert_eq!(entries[0]["actor"], "writer");
    assert_eq!(entries[0]["action"], "ingest");
    let rid = header(&written.1, "x-request-id").unwrap();
    assert_eq!(entries[0]["request_id"], rid);
    let text = audit_ops.2.to_string();
    assert!(!text.contains("secret"), "{text}");

    // gRPC: the same rules.
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{g}"))
        .await
        .unwrap();
    let e = client
        .list_motions(grpc_req(pb::ListMotionsRequest::default(), None))
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::Unauthenticated);
    let listed = client
        .list_motions(grpc_req(
            pb::ListMotionsRequest::default(),
            Some("reader-secret"),
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(listed.motions.len(), 1);
    let id = listed.motions[0].id;
    let e = client
        .delete_motion(grpc_req(pb::MotionId { id }, Some("reader-secret")))
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::PermissionDenied);
    let mut del = grpc_req(pb::MotionId { id }, Some("ops-secret"));
    del.metadata_mut()
        .insert("x-request-id", "delete-by-ops-1".parse().unwrap());
    client.delete_motion(del).await.unwrap();
    let e = client
        .list_audit(grpc_req(
            pb::ListAuditRequest { limit: 5 },
            Some("writer-secret"),
        ))
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::PermissionDenied);
    let audit = client
        .list_audit(grpc_req(
            pb::ListAuditRequest { limit: 5 },
            Some("ops-secret"),
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(audit.entries[0].action, "delete");
    assert_eq!(audit.entries[0].actor, "ops");
    assert_eq!(audit.entries[0].request_id, "delete-by-ops-1");
    assert_eq!(audit.entries[0].target, format!("motion {id}"));

    // Revoked: the reader's line removed; refused within a second.
    std::fs::write(
        &tf,
        format!(
            "writer read,write {}\nops read,write,admin {}\n",
            hash_token("writer-secret"),
            hash_token("ops-secret")
        ),
    )
    .unwrap();
    let later = std::time::SystemTime::now() + std::time::Duration::from_secs(2);
    std::fs::File::options()
        .write(true)
        .open(&tf)
        .unwrap()
        .set_modified(later)
        .unwrap();
    tokio::time::sleep(std::time::Duration::from_millis(1200)).await;
    let revoked = tokio::task::spawn_blocking(move || {
        http(h, "GET", "/v1/motions", None, Some("reader-secret"))
    })
    .await
    .unwrap();
    assert_eq!(revoked.0, 401, "{}", revoked.2);
    // The change is in the audit trail, by name.
    let trail =
        tokio::task::spawn_blocking(move || http(h, "GET", "/v1/audit", None, Some("ops-secret")))
            .await
            .unwrap();
    let change = trail.2["entries"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["action"] == "tokens-change")
        .unwrap_or_else(|| panic!("{}", trail.2))
        .clone();
    assert!(
        change["target"]
            .as_str()
            .unwrap()
            .contains("removed [reader]"),
        "{change}"
    );
    assert!(!trail.2.to_string().contains("secret"), "{}", trail.2);
    let e = client
        .list_motions(grpc_req(
            pb::ListMotionsRequest::default(),
            Some("reader-secret"),
        ))
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::Unauthenticated);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_past_its_rate_gets_429_with_retry_after_and_others_keep_theirs() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = tokens_file(dir.path());
    let running = start(&config(dir.path(), Some(tokens), false, 5.0))
        .await
        .unwrap();
    let h = running.http;
    let g = running.grpc;
    let (storm, polite) = tokio::task::spawn_blocking(move || {
        let storm: Vec<(u16, String)> = (0..20)
            .map(|_| {
                let r = http(h, "GET", "/v1/motions", None, Some("reader-secret"));
                (r.0, r.1)
            })
            .collect();
        let polite = http(h, "GET", "/v1/motions", None, Some("writer-secret"));
        (storm, polite)
    })
    .await
    .unwrap();
    let limited: Vec<&(u16, String)> = storm.iter().filter(|r| r.0 == 429).collect();
    assert!(
        limited.len() >= 10,
        "{:?}",
        storm.iter().map(|r| r.0).collect::<Vec<_>>()
    );
    for (_, head) in &limited {
        let secs: u64 = header(head, "retry-after").unwrap().parse().unwrap();
        assert!(secs >= 1, "{head}");
    }
    // Another token's bucket is untouched.
    assert_eq!(polite.0, 200);
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{g}"))
        .await
        .unwrap();
    let e = client
        .list_motions(grpc_req(
            pb::ListMotionsRequest::default(),
            Some("reader-secret"),
        ))
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::ResourceExhausted);
    assert!(e.metadata().get("retry-after").is_some());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_access_settings_stop_start_up_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    // Nothing configured: every request would be refused.
    let e = start(&config(dir.path(), None, false, 0.0))
        .await
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("--public-read") && e.contains("--tokens"), "{e}");
    // Bad token files: the line named, with the reason.
    let p = dir.path().join("bad");
    for (lines, why) in [
        (
            format!(
                "a read {}\nb read,delete {}\n",
                hash_token("x"),
                hash_token("y")
            ),
            "delete",
        ),
        (
            format!("a read {}\na write {}\n", hash_token("x"), hash_token("y")),
            "twice",
        ),
    ] {
        std::fs::write(&p, lines).unwrap();
        let e = format!(
            "{:#}",
            start(&config(dir.path(), Some(p.clone()), false, 0.0))
                .await
                .err()
                .unwrap()
        );
        assert!(e.contains("line 2") && e.contains(why), "{e}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_token_of_collection_a_never_sees_collection_b() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("tokens");
    std::fs::write(
        &p,
        format!(
            "a-reader read a {}\na-writer read,write a {}\nb-reader read b {}\nops read,write,admin * {}\n",
            hash_token("ar"),
            hash_token("aw"),
            hash_token("br"),
            hash_token("ops")
        ),
    )
    .unwrap();
    let running = start(&config(dir.path(), Some(p), false, 0.0))
        .await
        .unwrap();
    let (h, g) = (running.http, running.grpc);
    let x = inline_motion("take_x", 0.0);
    let y = inline_motion("take_y", 1.7);
    let (ca, cb, into_b, into_nope, xa) = {
        let x = x.clone();
        tokio::task::spawn_blocking(move || {
            let ca = http(
                h,
                "POST",
                "/v1/collections",
                Some(&json!({"name": "a"})),
                Some("ops"),
            );
            let cb = http(
                h,
                "POST",
                "/v1/collections",
                Some(&json!({"name": "b"})),
                Some("ops"),
            );
            let body = |c: &str| json!({"motion": {"motion": x}, "collection": c});
            let into_b = http(h, "POST", "/v1/motions", Some(&body("b")), Some("aw"));
            let into_nope = http(h, "POST", "/v1/motions", Some(&body("nope")), Some("aw"));
            let xa = http(h, "POST", "/v1/motions", Some(&body("a")), Some("aw"));
            (ca, cb, into_b, into_nope, xa)
        })
        .await
        .unwrap()
    };
    assert_eq!(ca.0, 201, "{}", ca.2);
    assert_eq!(cb.0, 201, "{}", cb.2);
    // A collection not granted and one that does not exist: the same 404.
    assert_eq!(into_b.0, 404, "{}", into_b.2);
    assert_eq!(into_nope.0, 404, "{}", into_nope.2);
    assert_eq!(into_b.2["error"]["field"], "collection");
    assert_eq!(xa.0, 201, "{}", xa.2);
    let x_id = xa.2["motion_id"].as_i64().unwrap();
    // Y goes into B over gRPC.
    let mut client = pb::choreo_client::ChoreoClient::connect(format!("http://{g}"))
        .await
        .unwrap();
    let rot: Vec<f64> = y["rotations"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|f| {
            f.as_array()
                .unwrap()
                .iter()
                .flat_map(|j| j.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()))
        })
        .collect();
    let y_id = client
        .ingest_motion(grpc_req(
            pb::IngestRequest {
                motion: Some(pb::MotionSource {
                    source: Some(pb::motion_source::Source::Motion(pb::Motion {
                        fps: 60.0,
                        skeleton: "smpl24".into(),
                        rotations: rot,
                        translation: vec![0.0, 0.9, 0.0].repeat(140),
                        name: "take_y".into(),
                        ..Default::default()
                    })),
                }),
                collection: "b".into(),
                ..Default::default()
            },
            Some("ops"),
        ))
        .await
        .unwrap()
        .into_inner()
        .motion_id;

    let q_x = json!({"motion": {"motion": x}, "start_s": 0.1, "k": 10, "exact": true, "embedding": "dct"});
    let (list_a, get_y, bvh_y, query_y, hits_a, list_b) = {
        let q_x = q_x.clone();
        tokio::task::spawn_blocking(move || {
            (
                http(h, "GET", "/v1/motions", None, Some("ar")),
                http(h, "GET", &format!("/v1/motions/{y_id}"), None, Some("ar")),
                http(
                    h,
                    "GET",
                    &format!("/v1/motions/{y_id}/bvh"),
                    None,
                    Some("ar"),
                ),
                http(
                    h,
                    "POST",
                    "/v1/query",
                    Some(&json!({"motion": {"id": y_id}})),
                    Some("ar"),
                ),
                http(h, "POST", "/v1/query", Some(&q_x), Some("ar")),
                http(h, "GET", "/v1/motions", None, Some("br")),
            )
        })
        .await
        .unwrap()
    };
    let ids = |v: &Value| -> Vec<i64> {
        v["motions"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["id"].as_i64().unwrap())
            .collect()
    };
    assert_eq!(ids(&list_a.2), vec![x_id]);
    assert_eq!(ids(&list_b.2), vec![y_id]);
    assert_eq!(list_a.2["motions"][0]["collection"], "a");
    for r in [&get_y, &bvh_y, &query_y] {
        assert_eq!(r.0, 404, "{}", r.2);
    }
    assert_eq!(hits_a.0, 200, "{}", hits_a.2);
    let hits = hits_a.2["hits"].as_array().unwrap();
    assert!(!hits.is_empty());
    assert!(hits.iter().all(|h| h["motion_id"] == x_id), "{hits:?}");
    // gRPC: the same view.
    let listed = client
        .list_motions(grpc_req(pb::ListMotionsRequest::default(), Some("ar")))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        listed.motions.iter().map(|m| m.id).collect::<Vec<_>>(),
        vec![x_id]
    );
    let e = client
        .get_motion(grpc_req(pb::MotionId { id: y_id }, Some("ar")))
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::NotFound);
    let cols = client
        .list_collections(grpc_req(pb::ListCollectionsRequest::default(), Some("ar")))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(cols.names, vec!["a".to_string()]);

    // The same query in a store that holds only X gives the same hits.
    let dir2 = tempfile::tempdir().unwrap();
    let only = start(&config(
        dir2.path(),
        Some(tokens_file(dir2.path())),
        false,
        0.0,
    ))
    .await
    .unwrap();
    let h2 = only.http;
    let hits_only = tokio::task::spawn_blocking(move || {
        let put = json!({"motion": {"motion": x}});
        assert_eq!(
            http(h2, "POST", "/v1/motions", Some(&put), Some("writer-secret")).0,
            201
        );
        http(h2, "POST", "/v1/query", Some(&q_x), Some("reader-secret"))
    })
    .await
    .unwrap();
    let key = |v: &Value| -> Vec<(i64, String)> {
        v["hits"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| {
                (
                    h["start_frame"].as_i64().unwrap(),
                    format!("{:.6}", h["score"].as_f64().unwrap()),
                )
            })
            .collect()
    };
    assert_eq!(key(&hits_a.2), key(&hits_only.2));
}
