//! Who may do what: scoped bearer tokens, open reads only when asked for,
//! and a token bucket per client.
//!
//! Tokens come from `--token` (one token with every scope, as before) and
//! from a token file (`--tokens FILE`), one per line:
//!
//! ```text
//! # name       scopes            collections      secret (SHA-256 of the token, hex)
//! archivist    read              *                sha256:9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08
//! studio-a     read,write        company-a,prod1  sha256:…
//! ops          read,write,admin  *                sha256:…
//! ```
//!
//! A token sees (and writes) only its collections; `*` is every one. A
//! three-field line (no collections) means `*`.
//!
//! Scopes: `read` (query, get, export, list, classify, generate and the
//! other model endpoints), `write` (ingest, delete), `admin` (the audit
//! trail). Only hashes are kept; a presented token is hashed and compared
//! with every entry in constant time. The file is read again when it
//! changes (checked twice a second), so a line removed is a token revoked
//! within half a second; a file that no longer parses keeps the tokens in
//! force and logs why. Secrets never reach a log line.
//!
//! Reads without a token are refused unless the server was started with
//! `--public-read`.

use super::ApiError;
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant, SystemTime};

/// What a request needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scope {
    Read = 1,
    Write = 2,
    Admin = 4,
}

impl Scope {
    pub fn name(self) -> &'static str {
        match self {
            Scope::Read => "read",
            Scope::Write => "write",
            Scope::Admin => "admin",
        }
    }
    fn parse(s: &str) -> Option<Scope> {
        match s {
            "read" => Some(Scope::Read),
            "write" => Some(Scope::Write),
            "admin" => Some(Scope::Admin),
            _ => None,
        }
    }
}

const ALL_SCOPES: u8 = Scope::Read as u8 | Scope::Write as u8 | Scope::Admin as u8;

/// A token file line: name, scopes, collections (`None` = all), hash.
pub type TokenLine = (String, u8, Option<Vec<String>>, [u8; 32]);

#[derive(Clone, Debug, PartialEq)]
struct Entry {
    name: String,
    scopes: u8,
    collections: Option<Vec<String>>,
    hash: [u8; 32],
    /// From `--token` (kept when the file is read again).
    from_flag: bool,
}

/// Who a request is: a token's name (never the token), or `anonymous`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Principal {
    pub name: String,
    scopes: u8,
    /// The collections it may see and write; `None` = all.
    pub collections: Option<Vec<String>>,
}

impl Principal {
    /// A caller without a token, under `--public-read`: reads everything.
    pub fn anonymous() -> Self {
        Principal {
            name: "anonymous".into(),
            scopes: Scope::Read as u8,
            collections: None,
        }
    }
    pub fn may(&self, s: Scope) -> bool {
        self.scopes & s as u8 != 0
    }
    /// Whether it may see (and, with `write`, write) this collection.
    pub fn sees(&self, collection: &str) -> bool {
        self.collections
            .as_ref()
            .is_none_or(|cs| cs.iter().any(|c| c == collection))
    }
}

/// `sha256:<hex>` of a token: what a token file holds.
pub fn hash_token(token: &str) -> String {
    let d = Sha256::digest(token.as_bytes());
    format!(
        "sha256:{}",
        d.iter().map(|b| format!("{b:02x}")).collect::<String>()
    )
}

fn digest(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

/// Parse a token file; errors name the file and the line.
pub fn parse_tokens(file: &str, text: &str) -> Result<Vec<TokenLine>, String> {
    let mut out: Vec<TokenLine> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let at = |why: String| format!("{file}: line {}: {why}", i + 1);
        let fields: Vec<&str> = line.split_whitespace().collect();
        let (name, scopes, collections, secret) = match fields.as_slice() {
            [n, s, h] => (n, s, None, h),
            [n, s, c, h] => (n, s, Some(c), h),
            _ => {
                return Err(at(format!(
                    "expected `name scopes [collections] sha256:<hex>`, found {} fields",
                    fields.len()
                )))
            }
        };
        let collections = match collections {
            None => None,
            Some(c) if *c == "*" => None,
            Some(c) => {
                let list: Vec<String> = c.split(',').map(str::to_string).collect();
                if let Some(bad) = list.iter().find(|c| !valid_collection_name(c)) {
                    return Err(at(format!(
                        "collection {bad:?}: 1 to 64 letters, digits and - _ . only"
                    )));
                }
                Some(list)
            }
        };
        if !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.@".contains(c))
        {
            return Err(at(format!(
                "name {name:?}: letters, digits and - _ . @ only"
            )));
        }
        if out.iter().any(|e| e.0 == **name) {
            return Err(at(format!("name {name:?} is given twice")));
        }
        let mut bits = 0u8;
        for s in scopes.split(',') {
            bits |= Scope::parse(s)
                .ok_or_else(|| at(format!("unknown scope {s:?} (read, write, admin)")))?
                as u8;
        }
        let hex = secret.strip_prefix("sha256:").ok_or_else(|| {
            at("the secret must be `sha256:<64 hex digits>`, never the token itself".into())
        })?;
        if hex.len() != 64 || !hex.chars().all(|c| c.is_ascii_hexdigit()) {
            return Err(at("the secret must be `sha256:<64 hex digits>`".into()));
        }
        let mut h = [0u8; 32];
        for (k, b) in h.iter_mut().enumerate() {
            *b = u8::from_str_radix(&hex[2 * k..2 * k + 2], 16).expect("hex checked");
        }
        if out.iter().any(|e| e.3 == h) {
            return Err(at("the same secret is given to two names".into()));
        }
        out.push((name.to_string(), bits, collections, h));
    }
    Ok(out)
}

/// A collection's name: 1 to 64 ASCII letters, digits, `-`, `_`, `.`.
pub fn valid_collection_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
}

/// Token buckets keyed by client.
struct Limiter {
    rate: f64,
    burst: f64,
    buckets: Mutex<HashMap<String, (f64, Instant)>>,
}

impl Limiter {
    /// `Ok` to go ahead, or the seconds until a request would be allowed.
    fn take(&self, key: &str) -> Result<(), f64> {
        if self.rate <= 0.0 {
            return Ok(());
        }
        let now = Instant::now();
        let mut b = self.buckets.lock().expect("buckets");
        if b.len() > 100_000 {
            // Forget clients idle long enough to be full again.
            let full = self.burst / self.rate;
            b.retain(|_, (_, t)| now.duration_since(*t).as_secs_f64() < full);
        }
        let (tokens, last) = b.entry(key.to_string()).or_insert((self.burst, now));
        *tokens = (*tokens + now.duration_since(*last).as_secs_f64() * self.rate).min(self.burst);
        *last = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            Ok(())
        } else {
            Err((1.0 - *tokens) / self.rate)
        }
    }
}

/// The server's access rules.
pub struct Auth {
    entries: RwLock<Vec<Entry>>,
    public_read: bool,
    file: Option<(PathBuf, Mutex<Option<SystemTime>>)>,
    limiter: Limiter,
}

/// How [`Auth`] is configured (the server's flags).
#[derive(Clone, Debug, Default)]
pub struct AuthConfig {
    /// `--token`: one token with every scope, named `token`.
    pub token: Option<String>,
    /// `--tokens FILE`.
    pub tokens_file: Option<PathBuf>,
    /// `--public-read`: reads need no token.
    pub public_read: bool,
    /// `--rate-limit`: requests per second per client (0 = no limit).
    pub rate_limit: f64,
    /// `--rate-burst`: the bucket's size.
    pub rate_burst: f64,
}

impl Auth {
    pub fn new(cfg: &AuthConfig) -> Result<Auth, String> {
        let mut entries = Vec::new();
        if let Some(t) = cfg.token.as_deref().filter(|t| !t.is_empty()) {
            entries.push(Entry {
                name: "token".into(),
                scopes: ALL_SCOPES,
                collections: None,
                hash: digest(t),
                from_flag: true,
            });
        }
        let file = match &cfg.tokens_file {
            Some(p) => {
                let (list, mtime) = read_file(p)?;
                for (name, scopes, collections, hash) in list {
                    if entries.iter().any(|e| e.name == name) {
                        return Err(format!(
                            "{}: the name {name:?} is taken by --token",
                            p.display()
                        ));
                    }
                    entries.push(Entry {
                        name,
                        scopes,
                        collections,
                        hash,
                        from_flag: false,
                    });
                }
                Some((p.clone(), Mutex::new(mtime)))
            }
            None => None,
        };
        if !(cfg.rate_limit.is_finite() && cfg.rate_limit >= 0.0) {
            return Err(format!("--rate-limit: {} is not a rate", cfg.rate_limit));
        }
        Ok(Auth {
            entries: RwLock::new(entries),
            public_read: cfg.public_read,
            file,
            limiter: Limiter {
                rate: cfg.rate_limit,
                burst: cfg.rate_burst.max(1.0),
                buckets: Mutex::new(HashMap::new()),
            },
        })
    }

    /// Whether any token is configured.
    pub fn has_tokens(&self) -> bool {
        !self.entries.read().expect("tokens").is_empty()
    }
    /// Read the token file again if it changed. Called twice a second by
    /// the server. Returns what changed (token names only), for the audit
    /// trail.
    pub fn reload(&self) -> Option<String> {
        let (path, seen) = self.file.as_ref()?;
        let mtime = std::fs::metadata(path).and_then(|m| m.modified()).ok();
        let mut seen = seen.lock().expect("mtime");
        if mtime == *seen {
            return None;
        }
        *seen = mtime;
        match read_file(path) {
            Ok((list, _)) => {
                let mut e = self.entries.write().expect("tokens");
                let old: Vec<Entry> = e.iter().filter(|x| !x.from_flag).cloned().collect();
                e.retain(|x| x.from_flag);
                let new: Vec<Entry> = list
                    .into_iter()
                    .map(|(name, scopes, collections, hash)| Entry {
                        name,
                        scopes,
                        collections,
                        hash,
                        from_flag: false,
                    })
                    .filter(|n| !e.iter().any(|f| f.name == n.name))
                    .collect();
                let names = |v: &[&Entry]| {
                    v.iter()
                        .map(|x| x.name.as_str())
                        .collect::<Vec<_>>()
                        .join(",")
                };
                let added: Vec<&Entry> = new
                    .iter()
                    .filter(|n| !old.iter().any(|o| o.name == n.name))
                    .collect();
                let removed: Vec<&Entry> = old
                    .iter()
                    .filter(|o| !new.iter().any(|n| n.name == o.name))
                    .collect();
                let changed: Vec<&Entry> = new
                    .iter()
                    .filter(|n| old.iter().any(|o| o.name == n.name && o != *n))
                    .collect();
                let summary = format!(
                    "token file {}: added [{}] removed [{}] changed [{}]",
                    path.display(),
                    names(&added),
                    names(&removed),
                    names(&changed)
                );
                let any = !added.is_empty() || !removed.is_empty() || !changed.is_empty();
                e.extend(new);
                tracing::info!("{summary}");
                any.then_some(summary)
            }
            Err(why) => {
                tracing::error!("token file not reloaded, the old tokens stay: {why}");
                None
            }
        }
    }

    /// Who presents `presented` (the bearer token, if any), allowed `need`?
    /// 401 without a usable token (unless reads are public), 403 with one
    /// that lacks the scope.
    pub fn authorize(&self, presented: Option<&str>, need: Scope) -> Result<Principal, ApiError> {
        if !self.has_tokens() {
            // No tokens at all: a presented one means nothing.
            if need == Scope::Read && self.public_read {
                return Ok(Principal::anonymous());
            }
            return Err(ApiError::PermissionDenied(format!(
                "{} requests are switched off: start the server with --token (CHOREO_TOKEN) or --tokens",
                need.name()
            )));
        }
        let Some(tok) = presented else {
            if need == Scope::Read && self.public_read {
                return Ok(Principal::anonymous());
            }
            return Err(ApiError::Unauthenticated(format!(
                "this request needs `{}` access: send the header `Authorization: Bearer <token>`",
                need.name()
            )));
        };
        let h = digest(tok);
        let entries = self.entries.read().expect("tokens");
        // Compare with every entry, without stopping at a match.
        let mut found: Option<&Entry> = None;
        for e in entries.iter() {
            let eq = e
                .hash
                .iter()
                .zip(h.iter())
                .fold(0u8, |a, (x, y)| a | (x ^ y))
                == 0;
            if eq {
                found = Some(e);
            }
        }
        let Some(e) = found else {
            return Err(ApiError::Unauthenticated(
                "the bearer token is not known (wrong or revoked)".into(),
            ));
        };
        let p = Principal {
            name: e.name.clone(),
            scopes: e.scopes,
            collections: e.collections.clone(),
        };
        if !p.may(need) {
            return Err(ApiError::PermissionDenied(format!(
                "the token {:?} has no `{}` scope",
                p.name,
                need.name()
            )));
        }
        Ok(p)
    }

    /// Take one request from the caller's bucket: a token's name, or the
    /// address of an anonymous caller. `Err(seconds)` when it is empty.
    pub fn admit(&self, who: &Principal, addr: Option<IpAddr>) -> Result<(), ApiError> {
        let key = if who.name == "anonymous" {
            format!("addr:{}", addr.map_or("unknown".into(), |a| a.to_string()))
        } else {
            format!("token:{}", who.name)
        };
        self.limiter
            .take(&key)
            .map_err(|wait| ApiError::RateLimited {
                reason: format!(
                    "{} is over its limit of {} requests/s; retry after {:.1} s",
                    if who.name == "anonymous" {
                        "this address".to_string()
                    } else {
                        format!("token {:?}", who.name)
                    },
                    self.limiter.rate,
                    wait
                ),
                retry_after_s: wait.ceil().max(1.0) as u64,
            })
    }
}

fn read_file(p: &Path) -> Result<(Vec<TokenLine>, Option<SystemTime>), String> {
    let name = p.display().to_string();
    let text = std::fs::read_to_string(p).map_err(|e| format!("{name}: {e}"))?;
    let mtime = std::fs::metadata(p).and_then(|m| m.modified()).ok();
    Ok((parse_tokens(&name, &text)?, mtime))
}

/// Reload the token file twice a second for as long as `auth` lives; each
/// change goes into the audit trail (names only, never secrets).
pub fn spawn_reloader(auth: Arc<Auth>, store: crate::store::Store) {
    if auth.file.is_none() {
        return;
    }
    let weak = Arc::downgrade(&auth);
    drop(auth);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(500));
        loop {
            tick.tick().await;
            let Some(a) = weak.upgrade() else {
                return;
            };
            if let Some(change) = a.reload() {
                if let Err(e) = store
                    .audit_append("token-file", "tokens-change", &change, "")
                    .await
                {
                    tracing::error!("audit trail: {e}");
                }
            }
        }
    });
}

/// The scope a REST route needs.
pub fn rest_scope(method: &axum::http::Method, path: &str) -> Option<Scope> {
    use axum::http::Method;
    if !path.starts_with("/v1/") {
        return None;
    }
    Some(match (method, path) {
        (&Method::POST, "/v1/motions") => Scope::Write,
        (&Method::DELETE, p) if p.starts_with("/v1/motions/") => Scope::Write,
        (_, p) if p.starts_with("/v1/audit") => Scope::Admin,
        (&Method::POST, "/v1/collections") => Scope::Admin,
        _ => Scope::Read,
    })
}

/// The scope a gRPC method needs (`/choreo.v1.Choreo/IngestMotion`).
pub fn grpc_scope(path: &str) -> Option<Scope> {
    let method = path.strip_prefix("/choreo.v1.Choreo/")?;
    Some(match method {
        "IngestMotion" | "DeleteMotion" => Scope::Write,
        "ListAudit" | "CreateCollection" => Scope::Admin,
        _ => Scope::Read,
    })
}

#[cfg(test)]
mod tests;
