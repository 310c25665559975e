//! The SQLite store (sqlx), the source of truth: motions, their labels and
//! canonical channels, windows, embeddings, fitted models. Migrations in
//! `migrations/` run at open. Every write is one transaction that also bumps
//! `meta.generation`, which on-disk indexes compare against.

use crate::features::{Embedding, CHANNELS};
use crate::motion::io::ReadOptions;
use crate::motion::Labels;
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteSynchronous,
};
use sqlx::Row;
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
    pool: SqlitePool,
    path: PathBuf,
}

impl Store {
    /// Open (creating if missing) and migrate.
    pub async fn open(path: &Path) -> Result<Store> {
        let p = path.display().to_string();
        let opts = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Normal)
            .foreign_keys(true)
            .busy_timeout(Duration::from_secs(30));
        let pool = SqlitePoolOptions::new()
            .max_connections(4)
            .connect_with(opts)
            .await
            .map_err(|source| StoreError::Db {
                path: p.clone(),
                source,
            })?;
        sqlx::migrate!("./migrations")
            .run(&pool)
            .await
            .map_err(|source| StoreError::Migrate {
                path: p.clone(),
                source,
            })?;
        Ok(Store {
            pool,
            path: path.to_path_buf(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn db(&self, source: sqlx::Error) -> StoreError {
        StoreError::Db {
            path: self.path.display().to_string(),
            source,
        }
    }

    fn corrupt(&self, field: &str, reason: impl Into<String>) -> StoreError {
        StoreError::Corrupt {
            path: self.path.display().to_string(),
            field: field.into(),
            reason: reason.into(),
        }
    }

    /// SQLite's `PRAGMA integrity_check` and `foreign_key_check`: `Ok(())`
    /// when both find nothing wrong.
    pub async fn integrity_check(&self) -> Result<()> {
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
        sqlx::query_scalar("SELECT id FROM motions WHERE content_hash = ?")
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
        let id: i64 = sqlx::query_scalar(
            "INSERT INTO motions (id, source_path, content_hash, format, fps, frames, joints, skeleton, duration_s, labels, read_options, video, video_offset_s, collection)
             VALUES ((SELECT last + 1 FROM motion_id_seq), ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
        )
        .bind(&m.source_path)
        .bind(&m.content_hash)
        .bind(&m.format)
        .bind(m.fps)
        .bind(m.frames as i64)
        .bind(m.joints as i64)
        .bind(&m.skeleton)
        .bind(m.duration_s)
        .bind(labels)
        .bind(
            (!m.read_options.is_default())
                .then(|| serde_json::to_string(&m.read_options).expect("read options serialise")),
        )
        .bind(m.video.as_ref().map(|v| v.video.clone()))
        .bind(m.video.as_ref().map(|v| v.video_offset_s))
        .bind(&m.collection)
        .fetch_one(&mut *tx)
        .await
        .map_err(|e| self.db(e))?;
        insert_labels(&mut tx, id, &m.labels)
            .await
            .map_err(|e| self.db(e))?;
        let flat: Vec<f32> = m.channels.iter().flat_map(|r| r.iter().copied()).collect();
        sqlx::query(
            "INSERT INTO motion_channels (motion_id, fps, frames, data) VALUES (?, 60.0, ?, ?)",
        )
        .bind(id)
        .bind(m.channels.len() as i64)
        .bind(f32s_to_blob(&flat))
        .execute(&mut *tx)
        .await
        .map_err(|e| self.db(e))?;
        if let Some((name, bytes)) = &m.file {
            sqlx::query("INSERT INTO motion_files (motion_id, name, bytes) VALUES (?, ?, ?)")
                .bind(id)
                .bind(name)
                .bind(bytes)
                .execute(&mut *tx)
                .await
                .map_err(|e| self.db(e))?;
        }
        let mut window_ids = Vec::with_capacity(m.windows.len());
        for w in &m.windows {
            let wid: i64 = sqlx::query_scalar("INSERT INTO windows (motion_id, start_frame, frames) VALUES (?, ?, ?) RETURNING id")
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
            sqlx::query_scalar("SELECT labels FROM motions WHERE id = ?")
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
        sqlx::query("UPDATE motions SET labels = ? WHERE id = ?")
            .bind(serde_json::to_string(&merged).unwrap_or_else(|_| "{}".into()))
            .bind(id)
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?;
        sqlx::query("DELETE FROM motion_labels WHERE motion_id = ?")
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
        let n = sqlx::query("DELETE FROM motions WHERE id = ?")
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

    fn row_to_motion(&self, r: &sqlx::sqlite::SqliteRow) -> Result<MotionRow> {
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
        let row = sqlx::query("SELECT * FROM motions WHERE id = ?")
            .bind(id)
            .fetch_optional(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        row.map(|r| self.row_to_motion(&r)).transpose()
    }

    /// The stored source file of a motion (name, bytes), if kept.
    pub async fn motion_file(&self, id: i64) -> Result<Option<(String, Vec<u8>)>> {
        let row = sqlx::query("SELECT name, bytes FROM motion_files WHERE motion_id = ?")
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
            let found: Vec<i64> = sqlx::query_scalar("SELECT motion_id FROM motion_labels WHERE kind = ? AND value = ? ORDER BY motion_id")
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

    pub async fn count_embeddings(&self, kind: Embedding) -> Result<usize> {
        let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM embeddings WHERE kind = ?")
            .bind(kind.name())
            .fetch_one(&self.pool)
            .await
            .map_err(|e| self.db(e))?;
        Ok(n as usize)
    }

    /// All embeddings of one kind: (window id, vector).
    pub async fn embeddings(&self, kind: Embedding) -> Result<Vec<(i64, Vec<f32>)>> {
        let rows: Vec<(i64, Vec<u8>)> = sqlx::query_as(
            "SELECT window_id, vector FROM embeddings WHERE kind = ? ORDER BY window_id",
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
            "SELECT frames, substr(data, ?, ?) FROM motion_channels WHERE motion_id = ?",
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
            sqlx::query_scalar("SELECT vector FROM embeddings WHERE window_id = ? AND kind = ?")
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
        sqlx::query("DELETE FROM embeddings WHERE kind = ?")
            .bind(kind.name())
            .execute(&mut *tx)
            .await
            .map_err(|e| self.db(e))?;
        for (id, v) in rows {
            insert_embedding(&mut tx, *id, kind, v)
                .await
                .map_err(|e| self.db(e))?;
        }
        sqlx::query("INSERT INTO models (name, generation, body) VALUES (?, ?, ?) ON CONFLICT(name) DO UPDATE SET generation = excluded.generation, body = excluded.body")
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
            sqlx::query("INSERT INTO collections (name) VALUES (?) ON CONFLICT(name) DO NOTHING")
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
        sqlx::query("INSERT INTO audit (actor, action, target, request_id) VALUES (?, ?, ?, ?)")
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
            "SELECT id, at, actor, action, target, request_id FROM audit ORDER BY id DESC LIMIT ?",
        )
        .bind(limit)
        .fetch_all(&self.pool)
        .await
        .map_err(|e| self.db(e))
    }

    /// A stored model: (the generation it was fitted at, its JSON).
    pub async fn model(&self, name: &str) -> Result<Option<(i64, String)>> {
        sqlx::query_as("SELECT generation, body FROM models WHERE name = ?")
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
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    motion_id: i64,
    labels: &Labels,
) -> std::result::Result<(), sqlx::Error> {
    for (k, v) in labels {
        sqlx::query("INSERT INTO motion_labels (motion_id, kind, value) VALUES (?, ?, ?)")
            .bind(motion_id)
            .bind(k)
            .bind(v)
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

async fn insert_embedding(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    window_id: i64,
    kind: Embedding,
    v: &[f32],
) -> std::result::Result<(), sqlx::Error> {
    sqlx::query("INSERT INTO embeddings (window_id, kind, dim, vector) VALUES (?, ?, ?, ?)")
        .bind(window_id)
        .bind(kind.name())
        .bind(v.len() as i64)
        .bind(f32s_to_blob(v))
        .execute(&mut **tx)
        .await?;
    Ok(())
}

async fn bump_generation(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
) -> std::result::Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE meta SET value = CAST(CAST(value AS INTEGER) + 1 AS TEXT) WHERE key = 'generation'",
    )
    .execute(&mut **tx)
    .await?;
    Ok(())
}
