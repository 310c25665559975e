//! Motions: insert (with their channels, windows and embeddings, in one
//! transaction), look up, merge labels, delete, list and filter.

use super::*;
use sqlx::any::AnyRow;

impl Store {
    pub async fn motion_by_hash(&self, hash: &str) -> Result<Option<i64>> {
        sqlx::query_scalar("SELECT id FROM motions WHERE content_hash = $1")
            .bind(hash)
            .fetch_optional(&self.pool)
            .await
            .map_err(|e| self.db(e))
    }

    /// Insert a motion, its channels, windows and embeddings in one
    /// transaction: its id and window ids (in the order of `m.windows`), or,
    /// when another writer (a replica) stored the same content first, that
    /// motion's id.
    pub async fn insert_motion(&self, m: &NewMotion) -> Result<Inserted> {
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
            // Another writer stored the same content between the caller's
            // lookup and this insert: roll back, answer with its id.
            Err(sqlx::Error::Database(e)) if e.is_unique_violation() => {
                drop(tx);
                return match self.motion_by_hash(&m.content_hash).await? {
                    Some(id) => Ok(Inserted::Existing(id)),
                    None => Err(self.corrupt(
                        "motions.content_hash",
                        format!("{} refused as stored, then not found", m.content_hash),
                    )),
                };
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
        Ok(Inserted::New { id, window_ids })
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
}

pub(super) async fn insert_labels(
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

pub(super) async fn insert_embedding(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    window_id: i64,
    kind: Embedding,
    v: &[f32],
) -> std::result::Result<(), sqlx::Error> {
    insert_embedding_sql(tx, window_id, kind, v, false).await
}

/// [`insert_embedding`], keeping a vector the window already has.
pub(super) async fn insert_embedding_if_new(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    window_id: i64,
    kind: Embedding,
    v: &[f32],
) -> std::result::Result<(), sqlx::Error> {
    insert_embedding_sql(tx, window_id, kind, v, true).await
}

async fn insert_embedding_sql(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    window_id: i64,
    kind: Embedding,
    v: &[f32],
    keep_existing: bool,
) -> std::result::Result<(), sqlx::Error> {
    let sql = if keep_existing {
        "INSERT INTO embeddings (window_id, kind, dim, vector) VALUES ($1, $2, $3, $4) ON CONFLICT (kind, window_id) DO NOTHING"
    } else {
        "INSERT INTO embeddings (window_id, kind, dim, vector) VALUES ($1, $2, $3, $4)"
    };
    sqlx::query(sql)
        .bind(window_id)
        .bind(kind.name())
        .bind(v.len() as i64)
        .bind(f32s_to_blob(v))
        .execute(&mut **tx)
        .await?;
    Ok(())
}

pub(super) async fn bump_generation(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
) -> std::result::Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE meta SET value = CAST(CAST(value AS BIGINT) + 1 AS TEXT) WHERE key = 'generation'",
    )
    .execute(&mut **tx)
    .await?;
    Ok(())
}
