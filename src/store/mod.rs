//! The store (sqlx), the source of truth: motions, their labels and
//! canonical channels, windows, embeddings, fitted models, the audit trail.
//! Two engines behind one API, through sqlx's `Any` driver: SQLite, one
//! embedded file (the default), and PostgreSQL, shared by many `choreo
//! serve` replicas. Each has its migrations (`migrations/sqlite`,
//! `migrations/postgres`), run at open; the SQL below is written once for
//! both (`$n` parameters), except where the dialects differ. Every write is
//! one transaction that also bumps `meta.generation`, which on-disk indexes
//! and other replicas compare against.

use crate::features::{Embedding, CHANNELS};
use crate::motion::io::ReadOptions;
use crate::motion::Labels;
use sqlx::any::AnyPoolOptions;
use sqlx::AnyPool;
use sqlx::{Executor, Row};
use std::path::{Path, PathBuf};
use std::time::Duration;

mod admin;
mod motions;
mod vectors;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{path}: database error: {source}")]
    Db {
        path: String,
        #[source]
        source: sqlx::Error,
    },
    #[error("{path}: migration failed: {source}")]
    Migrate {
        path: String,
        #[source]
        source: sqlx::migrate::MigrateError,
    },
    #[error("{path}: field `{field}`: {reason}")]
    Corrupt {
        path: String,
        field: String,
        reason: String,
    },
    /// The database cannot be reached (PostgreSQL down or restarting, a
    /// network cut): retry later. The API answers 503 / UNAVAILABLE.
    #[error("{path}: the store is unavailable: {reason}")]
    Unavailable { path: String, reason: String },
    /// A store migrated by a newer choreo.
    #[error("{path}: the store was migrated by a newer choreo (it has migration {found}; this build knows migrations up to {known}): upgrade choreo, or point it at another store")]
    TooNew {
        path: String,
        found: i64,
        known: i64,
    },
}

/// What [`Store::insert_motion`] did.
#[derive(Debug, PartialEq)]
pub enum Inserted {
    New {
        id: i64,
        window_ids: Vec<i64>,
    },
    /// Another writer stored the same content first: its motion.
    Existing(i64),
}

/// Which engine a store runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dialect {
    Sqlite,
    Postgres,
}

/// Where the store lives: a SQLite file (`--data-dir`), or a PostgreSQL
/// URL (`--store postgres://…`).
#[derive(Clone, Debug)]
pub enum Location {
    Sqlite(PathBuf),
    Postgres(String),
}

impl Location {
    /// A `--store` value: `postgres://` / `postgresql://` URLs, or
    /// `sqlite://PATH` / a plain path for SQLite.
    pub fn parse(s: &str) -> std::result::Result<Location, String> {
        let lower = s.to_ascii_lowercase();
        if lower.starts_with("postgres://") || lower.starts_with("postgresql://") {
            return Ok(Location::Postgres(s.to_string()));
        }
        if let Some(p) = s.strip_prefix("sqlite://") {
            return Ok(Location::Sqlite(PathBuf::from(p)));
        }
        if s.contains("://") {
            return Err(format!(
                "'{}' is not a store: give postgres://USER@HOST:PORT/DB, sqlite://PATH, or a file path",
                redact(s)
            ));
        }
        Ok(Location::Sqlite(PathBuf::from(s)))
    }
}

/// A URL with its password replaced by `***`, for messages and logs.
pub fn redact(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    let (auth, host) = match rest.rsplit_once('@') {
        Some(x) => x,
        None => return url.to_string(),
    };
    match auth.split_once(':') {
        Some((user, _)) => format!("{scheme}://{user}:***@{host}"),
        None => url.to_string(),
    }
}

pub type Result<T> = std::result::Result<T, StoreError>;

/// A motion as stored.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MotionRow {
    pub id: i64,
    pub source_path: String,
    pub content_hash: String,
    pub format: String,
    pub fps: f64,
    pub frames: i64,
    pub joints: i64,
    pub skeleton: String,
    pub duration_s: f64,
    pub labels: Labels,
    /// How the source file is read back (defaults when empty).
    #[serde(skip_serializing_if = "ReadOptions::is_default")]
    pub read_options: ReadOptions,
    #[serde(flatten)]
    pub video: Option<VideoLink>,
    /// The collection it belongs to (`default` unless ingest named one).
    pub collection: String,
}

/// The footage a motion came from.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VideoLink {
    /// A path or URL, as given at ingest.
    pub video: String,
    /// Video time of the motion's first frame, seconds.
    pub video_offset_s: f64,
}

/// One entry of the audit trail.
#[derive(Clone, Debug, PartialEq, serde::Serialize, sqlx::FromRow)]
pub struct AuditRow {
    pub id: i64,
    /// When, UTC, ISO 8601.
    pub at: String,
    /// The token's name (never the token).
    pub actor: String,
    pub action: String,
    pub target: String,
    pub request_id: String,
}

/// A motion to insert, with its windows and their embeddings.
pub struct NewMotion {
    pub source_path: String,
    pub content_hash: String,
    pub format: String,
    pub fps: f64,
    pub frames: usize,
    pub joints: usize,
    pub skeleton: String,
    pub duration_s: f64,
    pub labels: Labels,
    /// `[frames][72]` at 60 fps.
    pub channels: Vec<[f32; CHANNELS]>,
    pub windows: Vec<NewWindow>,
    /// The source file (name, bytes), kept in the store when given.
    pub file: Option<(String, Vec<u8>)>,
    pub read_options: ReadOptions,
    pub video: Option<VideoLink>,
    pub collection: String,
}

pub struct NewWindow {
    pub start_frame: usize,
    pub frames: usize,
    pub embeddings: Vec<(Embedding, Vec<f32>)>,
}

/// Where a window is.
#[derive(Clone, Copy, Debug)]
pub struct WindowRef {
    pub motion_id: i64,
    pub start_frame: i64,
}

pub fn f32s_to_blob(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

pub fn blob_to_f32s(b: &[u8]) -> Option<Vec<f32>> {
    if b.len() % 4 != 0 {
        return None;
    }
    Some(
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
    )
}

#[derive(Clone)]
pub struct Store {
    pool: AnyPool,
    dialect: Dialect,
    /// The SQLite file, or for PostgreSQL a local path that names this
    /// replica's index dumps (`DATA_DIR/postgres`).
    path: PathBuf,
    /// What errors and logs call the store (the file, or the URL without
    /// its password).
    label: String,
}

const INSERT_MOTION_SQLITE: &str = "INSERT INTO motions (id, source_path, content_hash, format, fps, frames, joints, skeleton, duration_s, labels, read_options, video, video_offset_s, collection)
     VALUES ((SELECT last + 1 FROM motion_id_seq), $1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13) RETURNING id";
const INSERT_MOTION_POSTGRES: &str = "INSERT INTO motions (id, source_path, content_hash, format, fps, frames, joints, skeleton, duration_s, labels, read_options, video, video_offset_s, collection)
     VALUES (nextval('motion_ids'), $1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13) RETURNING id";

static SQLITE_MIGRATIONS: sqlx::migrate::Migrator = sqlx::migrate!("./migrations/sqlite");
static POSTGRES_MIGRATIONS: sqlx::migrate::Migrator = sqlx::migrate!("./migrations/postgres");

/// How long a request waits for a database connection before the store
/// answers "unavailable" (PostgreSQL down) rather than hanging.
const ACQUIRE_TIMEOUT: Duration = Duration::from_secs(3);
/// How often a SQLite store's migrations are run again after failing (a
/// second process migrating the same new file at the same moment).
const MIGRATE_RETRIES: u32 = 5;

impl Store {
    /// Open (creating if missing) and migrate a SQLite store.
    pub async fn open(path: &Path) -> Result<Store> {
        Store::open_at(&Location::Sqlite(path.to_path_buf()), path.parent()).await
    }

    /// Open and migrate the store at `loc`. A PostgreSQL store keeps this
    /// replica's index dumps under `index_dir` (the data dir).
    pub async fn open_at(loc: &Location, index_dir: Option<&Path>) -> Result<Store> {
        sqlx::any::install_default_drivers();
        let (url, dialect, path, label) = match loc {
            Location::Sqlite(p) => {
                // sqlx reads `sqlite://PATH?mode=rwc`; an absolute path keeps
                // a relative one from being read as a host.
                let abs = match (p.parent(), p.file_name()) {
                    (Some(dir), Some(name)) if !dir.as_os_str().is_empty() => {
                        std::fs::create_dir_all(dir).ok();
                        dir.canonicalize()
                            .map(|d| d.join(name))
                            .unwrap_or_else(|_| p.clone())
                    }
                    _ => std::env::current_dir()
                        .map(|d| d.join(p))
                        .unwrap_or_else(|_| p.clone()),
                };
                let enc = abs
                    .display()
                    .to_string()
                    .replace('%', "%25")
                    .replace('?', "%3F")
                    .replace('#', "%23");
                (
                    format!("sqlite://{enc}?mode=rwc"),
                    Dialect::Sqlite,
                    p.clone(),
                    p.display().to_string(),
                )
            }
            Location::Postgres(u) => (
                u.clone(),
                Dialect::Postgres,
                index_dir.unwrap_or(Path::new(".")).join("postgres"),
                redact(u),
            ),
        };
        let lbl = label.clone();
        let fail = move |source: sqlx::Error| classify(&lbl, source);
        let opts = AnyPoolOptions::new()
            .max_connections(match dialect {
                Dialect::Sqlite => 4,
                Dialect::Postgres => 8,
            })
            .acquire_timeout(ACQUIRE_TIMEOUT)
            .after_connect(move |conn, _| {
                Box::pin(async move {
                    if dialect == Dialect::Sqlite {
                        for pragma in [
                            "PRAGMA foreign_keys = ON",
                            "PRAGMA busy_timeout = 30000",
                            "PRAGMA journal_mode = WAL",
                            "PRAGMA synchronous = NORMAL",
                        ] {
                            conn.execute(pragma).await?;
                        }
                    }
                    Ok(())
                })
            });
        if dialect == Dialect::Postgres {
            // One direct connection first: its error says why (refused,
            // unknown host, authentication), where the pool's would only
            // say that it timed out.
            let conn = <sqlx::AnyConnection as sqlx::Connection>::connect(&url)
                .await
                .map_err(&fail)?;
            let _ = sqlx::Connection::close(conn).await;
        }
        let pool = opts.connect(&url).await.map_err(&fail)?;
        let migrator = match dialect {
            Dialect::Sqlite => &SQLITE_MIGRATIONS,
            Dialect::Postgres => &POSTGRES_MIGRATIONS,
        };
        // Refuse a store migrated by a newer choreo, naming the versions.
        let known = migrator.iter().map(|m| m.version).max().unwrap_or(0);
        let mut conn = pool.acquire().await.map_err(&fail)?;
        let newest: Option<i64> =
            sqlx::query_scalar("SELECT MAX(version) FROM _sqlx_migrations WHERE success")
                .fetch_one(&mut *conn)
                .await
                .unwrap_or(None);
        drop(conn);
        if let Some(found) = newest.filter(|v| *v > known) {
            return Err(StoreError::TooNew {
                path: label,
                found,
                known,
            });
        }
        // SQLite has no advisory lock: two processes opening a new store at
        // once (an ingest and a server) both find no migration applied,
        // and the second's CREATE fails on the first's table. Each
        // migration commits whole, so running again a moment later finds
        // it applied and goes on from there.
        let mut tries = 0;
        loop {
            match migrator.run(&pool).await {
                Ok(()) => break,
                Err(_) if dialect == Dialect::Sqlite && tries < MIGRATE_RETRIES => {
                    tries += 1;
                    tokio::time::sleep(Duration::from_millis(100 * tries as u64)).await;
                }
                Err(source) => {
                    return Err(StoreError::Migrate {
                        path: label.clone(),
                        source,
                    })
                }
            }
        }
        Ok(Store {
            pool,
            dialect,
            path,
            label,
        })
    }

    pub fn dialect(&self) -> Dialect {
        self.dialect
    }

    /// What messages call the store: its file, or its URL without the
    /// password.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The SQLite file, or for PostgreSQL the local base name of this
    /// replica's index dumps.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn db(&self, source: sqlx::Error) -> StoreError {
        classify(&self.label, source)
    }

    fn corrupt(&self, field: &str, reason: impl Into<String>) -> StoreError {
        StoreError::Corrupt {
            path: self.label.clone(),
            field: field.into(),
            reason: reason.into(),
        }
    }

    /// SQLite's `PRAGMA integrity_check` and `foreign_key_check`: `Ok(())`
    /// when both find nothing wrong.
    pub async fn integrity_check(&self) -> Result<()> {
        if self.dialect == Dialect::Postgres {
            // PostgreSQL enforces its foreign keys on every write; reaching
            // it is the check.
            sqlx::query("SELECT 1")
                .execute(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
            return Ok(());
        }
        let r: String = sqlx::query_scalar("PRAGMA integrity_check")
            .fetch_one(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        if r != "ok" {
            return Err(self.corrupt("integrity_check", r));
        }
        let bad = sqlx::query("PRAGMA foreign_key_check")
            .fetch_all(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        if !bad.is_empty() {
            return Err(self.corrupt(
                "foreign_key_check",
                format!("{} rows point at nothing", bad.len()),
            ));
        }
        Ok(())
    }

    pub async fn generation(&self) -> Result<i64> {
        let v: String = sqlx::query_scalar("SELECT value FROM meta WHERE key = 'generation'")
            .fetch_one(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        v.parse()
            .map_err(|_| self.corrupt("meta.generation", format!("'{v}' is not an integer")))
    }
}

/// A database error as the store reports it: unreachable (connection
/// refused or reset, a pool timeout, the server shutting down) is
/// [`StoreError::Unavailable`], anything else [`StoreError::Db`].
fn classify(label: &str, source: sqlx::Error) -> StoreError {
    let unavailable = match &source {
        sqlx::Error::Io(_)
        | sqlx::Error::PoolTimedOut
        | sqlx::Error::PoolClosed
        | sqlx::Error::WorkerCrashed
        | sqlx::Error::Tls(_) => true,
        // 57P01 admin_shutdown, 57P02 crash_shutdown, 57P03 cannot_connect_now,
        // 08xxx connection exceptions.
        sqlx::Error::Database(e) => e
            .code()
            .is_some_and(|c| c.starts_with("57P") || c.starts_with("08")),
        sqlx::Error::Protocol(m) => m.contains("closed") || m.contains("unexpected"),
        _ => false,
    };
    if unavailable {
        StoreError::Unavailable {
            path: label.to_string(),
            reason: source.to_string(),
        }
    } else {
        StoreError::Db {
            path: label.to_string(),
            source,
        }
    }
}
