//! The REST contract, checked from outside: schemathesis (pip; in
//! scripts/requirements.txt) reads the served `openapi.json` and sends
//! what the document allows and what it forbids to a live server holding
//! the four AIST++ samples, then checks every answer: no 5xx, only
//! documented statuses, headers and content types, bodies that match their
//! schemas, forbidden requests refused, deleted resources gone (its
//! stateful phase ingests, reads and deletes through the links it infers).
//!
//! One check is left out, `positive_data_acceptance`: a request the schema
//! allows may still be refused for what a schema cannot say (a base64
//! string that is not a motion file, a segment past a clip's end, a stored
//! id another phase deleted). Those answers are 400 / 404 with the field
//! named, which the other checks hold to the document. And
//! `max_response_time`: speed lives in benchmarks, never in timed tests
//! (a 2,400-frame generation takes longer than its 10 s default).
//!
//! Skips without schemathesis (`st`) and fails instead under
//! `CHOREO_REQUIRE_REFS=1` (CI), like the other reference checks.

mod support;

use choreo::server::start;
use std::process::Command;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn schemathesis_finds_no_contract_failures() {
    if Command::new("st").arg("--version").output().is_err() {
        let why = "schemathesis (`st`) is not installed (pip install -r scripts/requirements.txt)";
        if std::env::var("CHOREO_REQUIRE_REFS").is_ok_and(|v| v == "1") {
            panic!("CHOREO_REQUIRE_REFS=1 but {why}");
        }
        eprintln!("SKIP: {why}");
        return;
    }
    let Some(aist) = choreo::data::require("aistpp/motions") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg = choreo::server::ServeConfig {
        ingest: vec![aist],
        token: Some("contract-secret".into()),
        ..support::serve_config(dir.path())
    };
    let running = start(&cfg).await.unwrap();
    let url = format!("http://{}/openapi.json", running.http);
    let out = tokio::task::spawn_blocking(move || {
        Command::new("st")
            .args(["run", &url])
            .args(["--header", "Authorization: Bearer contract-secret"])
            // Every check but positive_data_acceptance and max_response_time,
            // named (`all` would turn the latter on with a 10 s limit).
            .args([
                "--checks",
                "not_a_server_error,status_code_conformance,content_type_conformance,\
                 response_headers_conformance,response_schema_conformance,\
                 negative_data_rejection,missing_required_header,unsupported_method,\
                 allow_header_conformance,use_after_free,ensure_resource_availability,\
                 ignored_auth",
            ])
            // The WebSocket upgrades are not HTTP request/response pairs
            // (tests/browser_api.rs checks them).
            .args([
                "--exclude-path",
                "/v1/generate/ws",
                "--exclude-path",
                "/v1/duet/ws",
            ])
            .args(["--max-examples", "25", "--generation-deterministic"])
            // Boundary values are slow on purpose (2,400 generated frames, 5,000
            // interpolation steps): wait for them.
            .args(["--request-timeout", "600"])
            .env("NO_COLOR", "1")
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let tail: String = text
        .lines()
        .rev()
        .take(40)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect::<Vec<_>>()
        .join("\n");
    println!("{tail}");
    assert!(
        out.status.success(),
        "schemathesis found contract failures:\n{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    running.shutdown().await.unwrap();
}
