//! PostgreSQL for the tests: a fresh database per test on the server named
//! by `CHOREO_TEST_POSTGRES` (an admin URL, e.g.
//! `postgres://postgres@127.0.0.1:55432/postgres`; `.ci/run` starts a
//! throwaway one with `scripts/pg_throwaway.sh`), and `choreo serve`
//! replicas on it as child processes. Without the variable the tests skip
//! with a printed reason; under `CHOREO_REQUIRE_POSTGRES=1` (CI) they fail.
#![allow(dead_code)]

use base64::Engine;
use serde_json::{json, Value};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};

pub const TOKEN: &str = "replica-secret";

/// The admin URL, or `None` after printing why the test skips (a panic
/// under `CHOREO_REQUIRE_POSTGRES=1`).
pub fn admin_url() -> Option<String> {
    match std::env::var("CHOREO_TEST_POSTGRES") {
        Ok(u) if !u.is_empty() => Some(u),
        _ => {
            let why = "CHOREO_TEST_POSTGRES is not set (a PostgreSQL admin URL; scripts/pg_throwaway.sh start DIR PORT starts one)";
            if std::env::var("CHOREO_REQUIRE_POSTGRES").is_ok_and(|v| v == "1") {
                panic!("CHOREO_REQUIRE_POSTGRES=1 but {why}");
            }
            eprintln!("SKIP: {why}");
            None
        }
    }
}

/// A new, empty database on the server; returns its URL.
pub async fn fresh_db(admin: &str, tag: &str) -> String {
    use sqlx::{Connection, Executor};
    let name = format!(
        "choreo_{tag}_{}_{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_micros()
            % 1_000_000_000
    );
    let mut c = sqlx::PgConnection::connect(admin).await.unwrap();
    c.execute(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
        .await
        .unwrap();
    c.close().await.unwrap();
    let (base, _) = admin.rsplit_once('/').unwrap();
    format!("{base}/{name}")
}

/// `choreo serve --store URL` on free ports (no model: these tests need
/// the archive and search only); its REST address from its first line.
pub fn spawn_replica(url: &str, dir: &Path) -> (Child, SocketAddr) {
    super::spawn_choreo(
        Command::new(env!("CARGO_BIN_EXE_choreo"))
            .args(["serve", "--http-port", "0", "--grpc-port", "0"])
            .args(["--store", url])
            .arg("--data-dir")
            .arg(dir)
            .args([
                "--model",
                "/nonexistent-model",
                "--token",
                TOKEN,
                "--public-read",
            ])
            .args(["--sync-ms", "200"]),
    )
}

/// Real AIST++-VRM dances (sorted by name), as ingest bodies.
pub fn vrm_takes(n: usize) -> Option<Vec<(String, Value)>> {
    let dir = choreo::data::require("aistpp-vrm/motions")?;
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "pkl"))
        .collect();
    files.sort();
    files.truncate(n);
    Some(
        files
            .iter()
            .map(|f| {
                let name = f.file_name().unwrap().to_string_lossy().into_owned();
                let b64 =
                    base64::engine::general_purpose::STANDARD.encode(std::fs::read(f).unwrap());
                (
                    name.clone(),
                    json!({"motion": {"file": {"name": name, "content_base64": b64}}}),
                )
            })
            .collect(),
    )
}

/// A query for a stored motion's first window: the answer's status and the
/// top hit's motion id.
pub fn top_hit(h: SocketAddr, id: i64) -> (u16, Option<i64>) {
    match super::exchange(
        h,
        "POST",
        "/v1/query",
        Some(&json!({"motion": {"id": id}, "k": 1})),
        None,
    ) {
        Ok((s, _, v)) => (s, v["hits"][0]["motion_id"].as_i64()),
        Err(_) => (0, None),
    }
}

/// Stop a replica (SIGKILL) and reap it.
pub fn kill(mut c: Child) {
    let _ = c.kill();
    let _ = c.wait();
}
