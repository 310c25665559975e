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
use sqlx::any::{AnyPoolOptions, AnyRow};
use sqlx::AnyPool;
use sqlx::{Executor, Row};
use std::path::{Path, PathBuf};
use std::time::Duration;

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
    /// Another writer (a replica) stored the same content first.
    #[error("{path}: content {hash} is stored already")]
    Duplicate { path: String, hash: String },
    /// A store migrated by a newer choreo.
    #[error("{path}: the store was migrated by a newer choreo (it has migration {found}; this build knows migrations up to {known}): upgrade choreo, or point it at another store")]
    TooNew {
        path: String,
        found: i64,
        known: i64,
    },
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
        migrator
            .run(&pool)
            .await
            .map_err(|source| StoreError::Migrate {
                path: label.clone(),
                source,
            })?;
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

    pub async fn motion_by_hash(&self, hash: &str) -> Result<Option<i64>> {
        sqlx::query_scalar("SELECT id FROM motions WHERE content_hash = $1")
            .bind(hash)
            .fetch_optional(&self.pool)
            .await
            .map_err(|e| self.db(e))
    }

    /// Insert a motion, its channels, windows and embeddings in one
    /// transaction. Returns the motion id and its window ids (in the order
    /// of `m.windows`).
    pub async fn insert_motion(&self, m: &NewMotion) -> Result<(i64, Vec<i64>)> {
        let mut tx = self.pool.begin().await.map_err(|e| self.db(e))?;
        let labels = serde_json::to_string(&m.labels).unwrap_or_else(|_| "{}".into());
        // The next motion id: SQLite keeps the highest id ever given in a
        // table (one writer); PostgreSQL's sequence serves many writers.
        let sql = match self.dialect {
            Dialect::Sqlite => INSERT_MOTION_SQLITE,
            Dialect::Postgres => INSERT_MOTION_POSTGRES,
        };
        let inserted: std::result::Result<i64, sqlx::Error> =
            sqlx::query_scalar(sql)
                .bind(&m.source_path)
                .bind(&m.content_hash)
                .bind(&m.format)
                .bind(m.fps)
                .bind(m.frames as i64)
                .bind(m.joints as i64)
                .bind(&m.skeleton)
                .bind(m.duration_s)
                .bind(labels)
                .bind((!m.read_options.is_default()).then(|| {
                    serde_json::to_string(&m.read_options).expect("read options serialise")
                }))
                .bind(m.video.as_ref().map(|v| v.video.clone()))
                .bind(m.video.as_ref().map(|v| v.video_offset_s))
                .bind(&m.collection)
                .fetch_one(&mut *tx)
                .await;
        let id = match inserted {
            Ok(id) => id,
            // Another replica stored the same content between the caller's
            // lookup and this insert: the caller answers with its id.
            Err(sqlx::Error::Database(e)) if e.is_unique_violation() => {
                return Err(StoreError::Duplicate {
                    path: self.label.clone(),
                    hash: m.content_hash.clone(),
                })
            }
            Err(e) => return Err(self.db(e)),
        };
        insert_labels(&mut tx, id, &m.labels)
            .await
            .map_err(|e| self.db(e))?;
        let flat: Vec<f32> = m.channels.iter().flat_map(|r| r.iter().copied()).collect();
        sqlx::query(
            "INSERT INTO motion_channels (motion_id, fps, frames, data) VALUES ($1, 60.0, $2, $3)",
        )
        .bind(id)
        .bind(m.channels.len() as i64)
        .bind(f32s_to_blob(&flat))
        .execute(&mut *tx)
        .await
        .map_err(|e| self.db(e))?;
        if let Some((name, bytes)) = &m.file {
            sqlx::query("INSERT INTO motion_files (motion_id, name, bytes) VALUES ($1, $2, $3)")
                .bind(id)
                .bind(name)
                .bind(bytes)
                .execute(&mut *tx)
                .await
                .map_err(|e| self.db(e))?;
        }
        let mut window_ids = Vec::with_capacity(m.windows.len());
        for w in &m.windows {
            let wid: i64 = sqlx::query_scalar("INSERT INTO windows (motion_id, start_frame, frames) VALUES ($1, $2, $3) RETURNING id")
                .bind(id)
                .bind(w.start_frame as i64)
                .bind(w.frames as i64)
                .fetch_one(&mut *tx)
                .await
                .map_err(|e| self.db(e))?;
            for (kind, v) in &w.embeddings {
                insert_embedding(&mut tx, wid, *kind, v)
                    .await
                    .map_err(|e| self.db(e))?;
            }
            window_ids.push(wid);
        }
        bump_generation(&mut tx).await.map_err(|e| self.db(e))?;
        tx.commit().await.map_err(|e| self.db(e))?;
        Ok((id, window_ids))
    }

    /// Merge labels into a stored motion's (given values win). Returns the
    /// labels as stored afterwards, or `None` for an unknown id.
    pub async fn merge_labels(&self, id: i64, labels: &Labels) -> Result<Option<Labels>> {
        let mut tx = self.pool.begin().await.map_err(|e| self.db(e))?;
        let Some(current): Option<String> =
            sqlx::query_scalar("SELECT labels FROM motions WHERE id = $1")
                .bind(id)
                .fetch_optional(&mut *tx)
                .await
                .map_err(|e| self.db(e))?
        else {
            return Ok(None);
        };
        let mut merged: Labels = serde_json::from_str(&current)
            .map_err(|e| self.corrupt("motions.labels", e.to_string()))?;
        if labels.iter().all(|(k, v)| merged.get(k) == Some(v)) {
            return Ok(Some(merged));
        }
        merged.extend(labels.clone());
        sqlx::query("UPDATE motions SET labels = $1 WHERE id = $2")
            .bind(serde_json::to_string(&merged).unwrap_or_else(|_| "{}".into()))
            .bind(id)
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?;
        sqlx::query("DELETE FROM motion_labels WHERE motion_id = $1")
            .bind(id)
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?;
        insert_labels(&mut tx, id, &merged)
            .await
            .map_err(|e| self.db(e))?;
        bump_generation(&mut tx).await.map_err(|e| self.db(e))?;
        tx.commit().await.map_err(|e| self.db(e))?;
        Ok(Some(merged))
    }

    /// Remove a motion and everything derived from it.
    pub async fn delete_motion(&self, id: i64) -> Result<bool> {
        let mut tx = self.pool.begin().await.map_err(|e| self.db(e))?;
        let n = sqlx::query("DELETE FROM motions WHERE id = $1")
            .bind(id)
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?
            .rows_affected();
        if n == 0 {
            return Ok(false); // the transaction rolls back on drop
        }
        bump_generation(&mut tx).await.map_err(|e| self.db(e))?;
        tx.commit().await.map_err(|e| self.db(e))?;
        Ok(true)
    }

    fn row_to_motion(&self, r: &AnyRow) -> Result<MotionRow> {
        let labels: String = r.try_get("labels").map_err(|e| self.db(e))?;
        Ok(MotionRow {
            id: r.try_get("id").map_err(|e| self.db(e))?,
            source_path: r.try_get("source_path").map_err(|e| self.db(e))?,
            content_hash: r.try_get("content_hash").map_err(|e| self.db(e))?,
            format: r.try_get("format").map_err(|e| self.db(e))?,
            fps: r.try_get("fps").map_err(|e| self.db(e))?,
            frames: r.try_get("frames").map_err(|e| self.db(e))?,
            joints: r.try_get("joints").map_err(|e| self.db(e))?,
            skeleton: r.try_get("skeleton").map_err(|e| self.db(e))?,
            duration_s: r.try_get("duration_s").map_err(|e| self.db(e))?,
            labels: serde_json::from_str(&labels)
                .map_err(|e| self.corrupt("motions.labels", e.to_string()))?,
            collection: r.try_get("collection").map_err(|e| self.db(e))?,
            read_options: match r
                .try_get::<Option<String>, _>("read_options")
                .map_err(|e| self.db(e))?
            {
                None => ReadOptions::default(),
                Some(j) => serde_json::from_str(&j)
                    .map_err(|e| self.corrupt("motions.read_options", e.to_string()))?,
            },
            video: match r
                .try_get::<Option<String>, _>("video")
                .map_err(|e| self.db(e))?
            {
                None => None,
                Some(video) => Some(VideoLink {
                    video,
                    video_offset_s: r
                        .try_get::<Option<f64>, _>("video_offset_s")
                        .map_err(|e| self.db(e))?
                        .unwrap_or(0.0),
                }),
            },
        })
    }

    pub async fn motions(&self) -> Result<Vec<MotionRow>> {
        let rows = sqlx::query("SELECT * FROM motions ORDER BY id")
            .fetch_all(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        rows.iter().map(|r| self.row_to_motion(r)).collect()
    }

    pub async fn motion(&self, id: i64) -> Result<Option<MotionRow>> {
        let row = sqlx::query("SELECT * FROM motions WHERE id = $1")
            .bind(id)
            .fetch_optional(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        row.map(|r| self.row_to_motion(&r)).transpose()
    }

    /// The stored source file of a motion (name, bytes), if kept.
    pub async fn motion_file(&self, id: i64) -> Result<Option<(String, Vec<u8>)>> {
        let row = sqlx::query("SELECT name, bytes FROM motion_files WHERE motion_id = $1")
            .bind(id)
            .fetch_optional(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        row.map(|r| {
            Ok((
                r.try_get("name").map_err(|e| self.db(e))?,
                r.try_get("bytes").map_err(|e| self.db(e))?,
            ))
        })
        .transpose()
    }

    /// Ids of motions carrying every `kind=value` label.
    pub async fn motions_with_labels(&self, filters: &[(String, String)]) -> Result<Vec<i64>> {
        let mut ids: Option<Vec<i64>> = None;
        for (k, v) in filters {
            let found: Vec<i64> = sqlx::query_scalar("SELECT motion_id FROM motion_labels WHERE kind = $1 AND value = $2 ORDER BY motion_id")
                .bind(k)
                .bind(v)
                .fetch_all(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
            ids = Some(match ids {
                None => found,
                Some(prev) => prev
                    .into_iter()
                    .filter(|i| found.binary_search(i).is_ok())
                    .collect(),
            });
        }
        Ok(ids.unwrap_or_default())
    }

    /// Every window: id → (motion, start).
    pub async fn windows(&self) -> Result<Vec<(i64, WindowRef)>> {
        let rows: Vec<(i64, i64, i64)> =
            sqlx::query_as("SELECT id, motion_id, start_frame FROM windows ORDER BY id")
                .fetch_all(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        Ok(rows
            .into_iter()
            .map(|(id, motion_id, start_frame)| {
                (
                    id,
                    WindowRef {
                        motion_id,
                        start_frame,
                    },
                )
            })
            .collect())
    }

    /// One motion's windows: id → (motion, start), by id.
    pub async fn motion_windows(&self, motion_id: i64) -> Result<Vec<(i64, WindowRef)>> {
        let rows: Vec<(i64, i64)> =
            sqlx::query_as("SELECT id, start_frame FROM windows WHERE motion_id = $1 ORDER BY id")
                .bind(motion_id)
                .fetch_all(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        Ok(rows
            .into_iter()
            .map(|(id, start_frame)| {
                (
                    id,
                    WindowRef {
                        motion_id,
                        start_frame,
                    },
                )
            })
            .collect())
    }

    /// One motion's embeddings of one kind: (window id, vector), by window.
    pub async fn motion_embeddings(
        &self,
        motion_id: i64,
        kind: Embedding,
    ) -> Result<Vec<(i64, Vec<f32>)>> {
        let rows: Vec<(i64, Vec<u8>)> = sqlx::query_as(
            "SELECT e.window_id, e.vector FROM embeddings e JOIN windows w ON w.id = e.window_id
             WHERE w.motion_id = $1 AND e.kind = $2 ORDER BY e.window_id",
        )
        .bind(motion_id)
        .bind(kind.name())
        .fetch_all(&self.pool)
        .await
        .map_err(|e| self.db(e))?;
        rows.into_iter()
            .map(|(id, b)| {
                blob_to_f32s(&b).map(|v| (id, v)).ok_or_else(|| {
                    self.corrupt(
                        "embeddings.vector",
                        format!("window {id}: blob is not f32s"),
                    )
                })
            })
            .collect()
    }

    pub async fn count_embeddings(&self, kind: Embedding) -> Result<usize> {
        let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM embeddings WHERE kind = $1")
            .bind(kind.name())
            .fetch_one(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        Ok(n as usize)
    }

    /// All embeddings of one kind: (window id, vector).
    pub async fn embeddings(&self, kind: Embedding) -> Result<Vec<(i64, Vec<f32>)>> {
        let rows: Vec<(i64, Vec<u8>)> = sqlx::query_as(
            "SELECT window_id, vector FROM embeddings WHERE kind = $1 ORDER BY window_id",
        )
        .bind(kind.name())
        .fetch_all(&self.pool)
        .await
        .map_err(|e| self.db(e))?;
        rows.into_iter()
            .map(|(id, b)| {
                blob_to_f32s(&b).map(|v| (id, v)).ok_or_else(|| {
                    self.corrupt(
                        "embeddings.vector",
                        format!("window {id}: blob is not f32s"),
                    )
                })
            })
            .collect()
    }

    /// The canonical channels of every motion: (motion id, `[frames][72]`).
    pub async fn all_channels(&self) -> Result<Vec<(i64, Vec<[f32; CHANNELS]>)>> {
        let rows: Vec<(i64, Vec<u8>)> =
            sqlx::query_as("SELECT motion_id, data FROM motion_channels ORDER BY motion_id")
                .fetch_all(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        rows.into_iter()
            .map(|(id, b)| Ok((id, self.decode_channels(id, &b)?)))
            .collect()
    }

    fn decode_channels(&self, motion_id: i64, b: &[u8]) -> Result<Vec<[f32; CHANNELS]>> {
        let f = blob_to_f32s(b)
            .filter(|f| f.len() % CHANNELS == 0)
            .ok_or_else(|| {
                self.corrupt(
                    "motion_channels.data",
                    format!("motion {motion_id}: not a [frames][72] f32 matrix"),
                )
            })?;
        Ok(f.chunks_exact(CHANNELS)
            .map(|c| c.try_into().expect("72"))
            .collect())
    }

    /// Frames `start..start + frames` (clipped at the end) of one motion's
    /// channels, and its whole length in frames: only those bytes are read
    /// and decoded (`substr` of the blob). `None` for an unknown id.
    pub async fn channel_range(
        &self,
        motion_id: i64,
        start: usize,
        frames: usize,
    ) -> Result<Option<(usize, Vec<[f32; CHANNELS]>)>> {
        let row_bytes = CHANNELS * 4;
        let row: Option<(i64, Vec<u8>)> = sqlx::query_as(
            "SELECT frames, substr(data, CAST($1 AS INTEGER), CAST($2 AS INTEGER)) FROM motion_channels WHERE motion_id = $3",
        )
        .bind(start.saturating_mul(row_bytes).saturating_add(1) as i64)
        .bind(frames.saturating_mul(row_bytes) as i64)
        .bind(motion_id)
        .fetch_optional(&self.pool)
        .await
        .map_err(|e| self.db(e))?;
        row.map(|(total, b)| Ok((total.max(0) as usize, self.decode_channels(motion_id, &b)?)))
            .transpose()
    }

    /// Every label kind in the store with its values.
    pub async fn label_values(
        &self,
    ) -> Result<std::collections::BTreeMap<String, std::collections::BTreeSet<String>>> {
        let rows: Vec<(String, String)> =
            sqlx::query_as("SELECT DISTINCT kind, value FROM motion_labels")
                .fetch_all(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        let mut out = std::collections::BTreeMap::<_, std::collections::BTreeSet<_>>::new();
        for (k, v) in rows {
            out.entry(k).or_default().insert(v);
        }
        Ok(out)
    }

    /// One window's stored embedding of one kind.
    pub async fn embedding(&self, window_id: i64, kind: Embedding) -> Result<Option<Vec<f32>>> {
        let row: Option<Vec<u8>> =
            sqlx::query_scalar("SELECT vector FROM embeddings WHERE window_id = $1 AND kind = $2")
                .bind(window_id)
                .bind(kind.name())
                .fetch_optional(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        row.map(|b| {
            blob_to_f32s(&b).ok_or_else(|| {
                self.corrupt(
                    "embeddings.vector",
                    format!("window {window_id}: blob is not f32s"),
                )
            })
        })
        .transpose()
    }

    /// Replace every embedding of `kind` and store the model that made them,
    /// in one transaction.
    pub async fn replace_embeddings(
        &self,
        kind: Embedding,
        rows: &[(i64, Vec<f32>)],
        model_name: &str,
        model_body: &str,
        model_generation: i64,
    ) -> Result<()> {
        let mut tx = self.pool.begin().await.map_err(|e| self.db(e))?;
        sqlx::query("DELETE FROM embeddings WHERE kind = $1")
            .bind(kind.name())
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?;
        for (id, v) in rows {
            insert_embedding(&mut tx, *id, kind, v)
                .await
                .map_err(|e| self.db(e))?;
        }
        sqlx::query("INSERT INTO models (name, generation, body) VALUES ($1, $2, $3) ON CONFLICT(name) DO UPDATE SET generation = excluded.generation, body = excluded.body")
            .bind(model_name)
            .bind(model_generation)
            .bind(model_body)
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?;
        bump_generation(&mut tx).await.map_err(|e| self.db(e))?;
        tx.commit().await.map_err(|e| self.db(e))?;
        Ok(())
    }

    /// The collections, by name.
    pub async fn collections(&self) -> Result<Vec<String>> {
        sqlx::query_scalar("SELECT name FROM collections ORDER BY name")
            .fetch_all(&self.pool)
            .await
            .map_err(|e| self.db(e))
    }

    /// Create a collection; `false` when it exists already.
    pub async fn create_collection(&self, name: &str) -> Result<bool> {
        let r =
            sqlx::query("INSERT INTO collections (name) VALUES ($1) ON CONFLICT(name) DO NOTHING")
                .bind(name)
                .execute(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        Ok(r.rows_affected() == 1)
    }

    /// Append one entry to the audit trail.
    pub async fn audit_append(
        &self,
        actor: &str,
        action: &str,
        target: &str,
        request_id: &str,
    ) -> Result<()> {
        sqlx::query(
            "INSERT INTO audit (actor, action, target, request_id) VALUES ($1, $2, $3, $4)",
        )
        .bind(actor)
        .bind(action)
        .bind(target)
        .bind(request_id)
        .execute(&self.pool)
        .await
        .map_err(|e| self.db(e))?;
        Ok(())
    }

    /// The newest `limit` audit entries, newest first.
    pub async fn audit(&self, limit: i64) -> Result<Vec<AuditRow>> {
        sqlx::query_as(
            "SELECT id, at, actor, action, target, request_id FROM audit ORDER BY id DESC LIMIT $1",
        )
        .bind(limit)
        .fetch_all(&self.pool)
        .await
        .map_err(|e| self.db(e))
    }

    /// A stored model: (the generation it was fitted at, its JSON).
    pub async fn model(&self, name: &str) -> Result<Option<(i64, String)>> {
        sqlx::query_as("SELECT generation, body FROM models WHERE name = $1")
            .bind(name)
            .fetch_optional(&self.pool)
            .await
            .map_err(|e| self.db(e))
    }

    /// Counts for health checks and the ingest report.
    pub async fn counts(&self) -> Result<(usize, usize)> {
        let (m, w): (i64, i64) =
            sqlx::query_as("SELECT (SELECT COUNT(*) FROM motions), (SELECT COUNT(*) FROM windows)")
                .fetch_one(&self.pool)
                .await
                .map_err(|e| self.db(e))?;
        Ok((m as usize, w as usize))
    }

    /// A fingerprint of the windows table (count and largest id), which the
    /// PCA model records to know when it must be refitted.
    pub async fn windows_fingerprint(&self) -> Result<i64> {
        let (n, max): (i64, Option<i64>) = sqlx::query_as("SELECT COUNT(*), MAX(id) FROM windows")
            .fetch_one(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        Ok(n * 1_000_000_007 + max.unwrap_or(0))
    }
}

async fn insert_labels(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    motion_id: i64,
    labels: &Labels,
) -> std::result::Result<(), sqlx::Error> {
    for (k, v) in labels {
        sqlx::query("INSERT INTO motion_labels (motion_id, kind, value) VALUES ($1, $2, $3)")
            .bind(motion_id)
            .bind(k)
            .bind(v)
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

async fn insert_embedding(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    window_id: i64,
    kind: Embedding,
    v: &[f32],
) -> std::result::Result<(), sqlx::Error> {
    sqlx::query("INSERT INTO embeddings (window_id, kind, dim, vector) VALUES ($1, $2, $3, $4)")
        .bind(window_id)
        .bind(kind.name())
        .bind(v.len() as i64)
        .bind(f32s_to_blob(v))
        .execute(&mut **tx)
        .await?;
    Ok(())
}

async fn bump_generation(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
) -> std::result::Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE meta SET value = CAST(CAST(value AS BIGINT) + 1 AS TEXT) WHERE key = 'generation'",
    )
    .execute(&mut **tx)
    .await?;
    Ok(())
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
