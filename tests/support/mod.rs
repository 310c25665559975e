//! Helpers shared by the server tests: a server configuration on loopback
//! with free ports, and one HTTP/1.1 exchange over a fresh connection.
#![allow(dead_code)]

use choreo::server::ServeConfig;
use serde_json::Value;
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

/// A server over `dir` on loopback (free ports), the bundled models, reads
/// open, no token, no rate limit: tests change what they exercise.
pub fn serve_config(dir: &Path) -> ServeConfig {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    ServeConfig {
        data_dir: dir.to_path_buf(),
        store: None,
        sync_ms: 500,
        bind: "127.0.0.1".into(),
        http_port: 0,
        grpc_port: 0,
        max_body_mb: 64,
        workers: 2,
        ingest: vec![],
        model: root.join("models/default"),
        token: None,
        inbetweener: root.join("models/inbetween"),
        cors_origins: vec![],
        log_format: Default::default(),
        hnsw_backend: choreo::index::hnsw::Backend::Flat,
        vector_dtype: choreo::index::VectorDtype::F32,
        channel_cache_mb: choreo::search::DEFAULT_CHANNEL_CACHE_MB,
        hnsw_m: choreo::index::hnsw::HnswParams::default().m,
        hnsw_ef_construction: choreo::index::hnsw::HnswParams::default().ef_construction,
        runtime: choreo::lm::engine::Runtime::Tract,
        ort_lib: None,
        local_step: choreo::lm::engine::LocalStep::Kernel,
        tokens: None,
        public_read: true,
        rate_limit: 0.0,
        rate_burst: 20.0,
    }
}

/// One request with an optional JSON body and bearer token; returns the
/// status, the head (lower-cased) and the body as JSON (a body that is not
/// JSON comes back as a JSON string). Chunked bodies are joined.
pub fn exchange(
    addr: SocketAddr,
    method: &str,
    path: &str,
    body: Option<&Value>,
    token: Option<&str>,
) -> std::io::Result<(u16, String, Value)> {
    let bad = |what: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, what.to_string());
    let mut s = std::net::TcpStream::connect(addr)?;
    let b = body.map(|v| v.to_string()).unwrap_or_default();
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    // A server may answer before the body is all sent (a refused token):
    // like curl, read its answer even if the write was cut short.
    let _ = write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{b}",
        b.len()
    );
    let mut out = Vec::new();
    s.read_to_end(&mut out)?;
    let text = String::from_utf8_lossy(&out).to_string();
    let status: u16 = text
        .get(9..12)
        .and_then(|c| c.parse().ok())
        .ok_or_else(|| bad("no status line"))?;
    let (head, rest) = text
        .split_once("\r\n\r\n")
        .ok_or_else(|| bad("no end of headers"))?;
    let head = head.to_ascii_lowercase();
    let body = if head.contains("transfer-encoding: chunked") {
        let mut out = String::new();
        let mut r = rest;
        loop {
            let (len, tail) = r.split_once("\r\n").ok_or_else(|| bad("chunk"))?;
            let n = usize::from_str_radix(len.trim(), 16).map_err(|_| bad("chunk length"))?;
            if n == 0 {
                break;
            }
            out.push_str(tail.get(..n).ok_or_else(|| bad("short chunk"))?);
            r = tail.get(n + 2..).ok_or_else(|| bad("short chunk"))?;
        }
        out
    } else {
        rest.to_string()
    };
    Ok((
        status,
        head,
        serde_json::from_str(&body).unwrap_or(Value::String(body)),
    ))
}

/// A header's value from a lower-cased head.
pub fn header<'a>(head: &'a str, name: &str) -> Option<&'a str> {
    head.lines()
        .find_map(|l| l.strip_prefix(&format!("{name}: ")))
        .map(str::trim)
}
pub mod pg;

/// `choreo serve` as a child process with these arguments (free ports
/// are the caller's: pass `--http-port 0 --grpc-port 0`); returns it with
/// its REST address, read from its log line on stderr (the rest of its
/// stderr is drained in the background).
pub fn spawn_choreo(cmd: &mut std::process::Command) -> (std::process::Child, SocketAddr) {
    use std::io::BufRead;
    let mut child = cmd
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let addr = loop {
        let line = lines
            .next()
            .expect("the server exited before listening")
            .unwrap();
        if let Some((_, rest)) = line.split_once("choreo: REST on http://") {
            break rest.split(',').next().unwrap().parse().unwrap();
        }
    };
    std::thread::spawn(move || for _ in lines {});
    (child, addr)
}
