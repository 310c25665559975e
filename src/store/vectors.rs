//! Windows, their embeddings and the motions' channel matrices: what the
//! search indexes are built from and queries read.

use super::motions::{bump_generation, insert_embedding, insert_embedding_if_new};
use super::*;

impl Store {
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
        self.decode_vectors(rows)
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
        self.decode_vectors(rows)
    }

    /// (window id, blob) rows as (window id, f32 vector).
    fn decode_vectors(&self, rows: Vec<(i64, Vec<u8>)>) -> Result<Vec<(i64, Vec<f32>)>> {
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
        // Both are INTEGER (32-bit) to PostgreSQL: "the rest of the motion"
        // (a huge `frames`) is clamped to the largest, past any blob's end.
        .bind(start.saturating_mul(row_bytes).saturating_add(1).min(i32::MAX as usize) as i64)
        .bind(frames.saturating_mul(row_bytes).min(i32::MAX as usize) as i64)
        .bind(motion_id)
        .fetch_optional(&self.pool)
        .await
        .map_err(|e| self.db(e))?;
        row.map(|(total, b)| Ok((total.max(0) as usize, self.decode_channels(motion_id, &b)?)))
            .transpose()
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
    /// Add embeddings of one kind to windows that lack them (a window that
    /// has one keeps it), in one transaction.
    pub async fn add_embeddings(&self, kind: Embedding, rows: &[(i64, Vec<f32>)]) -> Result<()> {
        let mut tx = self.pool.begin().await.map_err(|e| self.db(e))?;
        for (id, v) in rows {
            insert_embedding_if_new(&mut tx, *id, kind, v)
                .await
                .map_err(|e| self.db(e))?;
        }
        bump_generation(&mut tx).await.map_err(|e| self.db(e))?;
        tx.commit().await.map_err(|e| self.db(e))?;
        Ok(())
    }

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
