//! Collections, the audit trail, fitted models and counts.

use super::*;

impl Store {
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
}
