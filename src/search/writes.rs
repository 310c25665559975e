//! The searcher's writes: ingest and delete reach the live indexes before
//! they answer; [`Searcher::maintain`] does the slow part afterwards.

use super::{Searcher, COMPACT_SHARE};
use crate::features::Embedding;
use crate::index::hnsw::HnswIndex;
use crate::index::AnnIndex;
use crate::motion::{Labels, MotionError};
use crate::search::ingest::{self, identity_hash, IngestOptions, Stored};
use crate::search::QueryError;
use crate::store::{Inserted, WindowRef};
use serde::Serialize;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// What [`Searcher::ingest`] did, with the labels merged into an already
/// stored motion.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IngestOutcome {
    #[serde(flatten)]
    pub stored: Stored,
    /// For an already-stored file sent with labels: the labels as stored now.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub merged_labels: Option<Labels>,
}

impl Searcher {
    /// Store one file's bytes and put its windows into every built index
    /// before answering. Idempotent by content hash; labels sent with a file
    /// already stored are merged into its labels.
    pub async fn ingest(
        &self,
        name: &str,
        bytes: Vec<u8>,
        opts: &IngestOptions,
    ) -> Result<Result<IngestOutcome, MotionError>, QueryError> {
        let hash = identity_hash(&opts.collection, &bytes);
        let _w = self.writes.lock().await;
        if let Some(id) = self.store.motion_by_hash(&hash).await? {
            return self.existing(id, opts).await.map(Ok);
        }
        let pca = self.catalog().pca.clone();
        let lm = self
            .lm_ready
            .load(Ordering::Acquire)
            .then(|| self.lm.get().cloned())
            .flatten();
        let (opts2, name2) = (opts.clone(), name.to_string());
        let prepared = tokio::task::spawn_blocking(move || {
            ingest::prepare_with(&name2, bytes, hash, &opts2, pca.as_deref(), lm.as_ref())
        })
        .await
        .map_err(|e| QueryError::Index(name.into(), format!("worker failed: {e}")))?;
        let m = match prepared {
            Ok(m) => m,
            Err(e) => return Ok(Err(e)),
        };
        let (motion_id, window_ids) = match self.store.insert_motion(&m).await? {
            Inserted::New { id, window_ids } => (id, window_ids),
            // Another replica stored the same content since the lookup
            // above: answer with its id, as if it had been here first.
            Inserted::Existing(id) => return self.existing(id, opts).await.map(Ok),
        };
        let row = self
            .store
            .motion(motion_id)
            .await?
            .ok_or(QueryError::NotFound(motion_id))?;
        let refs: Vec<(i64, WindowRef)> = window_ids
            .iter()
            .zip(&m.windows)
            .map(|(id, w)| {
                (
                    *id,
                    WindowRef {
                        motion_id,
                        start_frame: w.start_frame as i64,
                    },
                )
            })
            .collect();
        // The catalog first, then the indexes: hits are read through the
        // catalog, so a point already in an index but not yet in the
        // catalog would be dropped from a concurrent query's top k, while
        // a catalog entry whose point is not indexed yet is merely not
        // found for a moment.
        self.catalog
            .write()
            .expect("catalog lock")
            .add_motion(row, &refs);
        let built = self.built();
        let windows = m.windows;
        let ids = window_ids.clone();
        tokio::task::spawn_blocking(move || {
            for ((e, _, _), entry) in built {
                let items: Vec<(usize, Vec<f32>)> = ids
                    .iter()
                    .zip(&windows)
                    .filter_map(|(id, w)| {
                        let v = w.embeddings.iter().find(|(k, _)| *k == e).map(|(_, v)| v)?;
                        Some((*id as usize, v.clone()))
                    })
                    .collect();
                entry.ix.add_batch(&items);
                entry.dirty.store(true, Ordering::Release);
            }
        })
        .await
        .map_err(|e| QueryError::Index(name.into(), format!("worker failed: {e}")))?;
        self.wake.notify_one();
        Ok(Ok(IngestOutcome {
            stored: Stored::New {
                motion_id,
                windows: window_ids.len(),
            },
            merged_labels: None,
        }))
    }

    /// The answer for content already stored as motion `id`: labels sent
    /// with it are merged into its labels (and the catalog's copy).
    async fn existing(&self, id: i64, opts: &IngestOptions) -> Result<IngestOutcome, QueryError> {
        let mut merged_labels = None;
        if !opts.extra_labels.is_empty() {
            merged_labels = self.store.merge_labels(id, &opts.extra_labels).await?;
            if let (Some(l), Some(row)) = (
                &merged_labels,
                self.catalog
                    .write()
                    .expect("catalog lock")
                    .motions
                    .get_mut(&id),
            ) {
                row.labels = l.clone();
            }
        }
        Ok(IngestOutcome {
            stored: Stored::Existing { motion_id: id },
            merged_labels,
        })
    }

    /// Remove a stored motion; its windows vanish from the next query.
    /// `false` for an unknown id.
    pub async fn delete(&self, id: i64) -> Result<bool, QueryError> {
        let _w = self.writes.lock().await;
        if !self.store.delete_motion(id).await? {
            return Ok(false);
        }
        self.forget(id);
        self.wake.notify_one();
        Ok(true)
    }

    /// Take a deleted motion out of the catalog; its points stay in the
    /// indexes, hidden, until compaction (call with `writes` held).
    fn forget(&self, id: i64) {
        self.channels.forget(id);
        let gone = {
            let mut c = self.catalog.write().expect("catalog lock");
            c.motions.remove(&id);
            let ids = c.by_motion.remove(&id).unwrap_or_default();
            for w in &ids {
                c.windows.remove(w);
            }
            ids.len()
        };
        for (_, entry) in self.built() {
            entry.dead.fetch_add(gone, Ordering::AcqRel);
            entry.dirty.store(true, Ordering::Release);
        }
    }

    /// Catch up with writes made by other processes on the same store
    /// (replicas sharing one PostgreSQL, or `choreo ingest` on the same
    /// SQLite file): their motions go into every built index, motions they
    /// deleted are hidden, changed labels are taken, and a PCA basis they
    /// refitted is loaded and its indexes rebuilt. When nothing changed it
    /// costs one read of the store's generation. Returns whether it looked.
    pub async fn sync(&self) -> Result<bool, QueryError> {
        if self.store.generation().await? == self.synced.load(Ordering::Acquire) {
            return Ok(false);
        }
        let _w = self.writes.lock().await;
        let generation = self.store.generation().await?;
        let rows = self.store.motions().await?;
        let (added, removed) = {
            let mut c = self.catalog.write().expect("catalog lock");
            let live: std::collections::HashSet<i64> = rows.iter().map(|r| r.id).collect();
            let removed: Vec<i64> = c
                .motions
                .keys()
                .filter(|id| !live.contains(id))
                .copied()
                .collect();
            let mut added = Vec::new();
            for row in rows {
                match c.motions.get_mut(&row.id) {
                    Some(known) => *known = row,
                    None => added.push(row),
                }
            }
            (added, removed)
        };
        for id in &removed {
            self.forget(*id);
        }
        // A basis refitted elsewhere: load it, rebuild the PCA indexes.
        let stored_fit = self.store.model("pca").await?;
        let fit = stored_fit.as_ref().map_or(-1, |(g, _)| *g);
        let refitted = fit != self.pca_fit.load(Ordering::Acquire);
        if refitted {
            let pca = stored_fit.and_then(|(_, body)| serde_json::from_str(&body).ok());
            self.catalog.write().expect("catalog lock").pca = pca.map(Arc::new);
            self.pca_fit.store(fit, Ordering::Release);
        }
        let built = self.built();
        for row in added {
            let id = row.id;
            let windows = self.store.motion_windows(id).await?;
            // Catalog first, then the indexes (as in `ingest`).
            self.catalog
                .write()
                .expect("catalog lock")
                .add_motion(row, &windows);
            for ((e, _, _), entry) in &built {
                if refitted && *e == Embedding::Pca {
                    continue; // rebuilt whole below
                }
                let mut items: Vec<(usize, Vec<f32>)> = self
                    .store
                    .motion_embeddings(id, *e)
                    .await?
                    .into_iter()
                    .map(|(w, v)| (w as usize, v))
                    .collect();
                if *e == Embedding::Lm && items.len() < windows.len() {
                    // Stored by a replica that does not embed lm yet.
                    items = self.lm_for_motion(id, &windows).await?;
                }
                let ix = entry.ix.clone();
                tokio::task::spawn_blocking(move || ix.add_batch(&items))
                    .await
                    .map_err(|err| QueryError::Index(e.name().into(), err.to_string()))?;
                entry.dirty.store(true, Ordering::Release);
            }
        }
        if refitted {
            for (key, _) in built.into_iter().filter(|(k, _)| k.0 == Embedding::Pca) {
                let fresh = Arc::new(self.build(key, false).await?);
                self.indexes.lock().expect("index map").insert(key, fresh);
            }
        }
        self.synced.store(generation, Ordering::Release);
        Ok(true)
    }

    /// [`Searcher::backfill_lm`] under the write lock: every stored window
    /// gets its `lm` vector now, not at the first `lm` query.
    pub async fn prepare_lm(&self) -> Result<usize, QueryError> {
        let _w = self.writes.lock().await;
        self.backfill_lm().await
    }

    /// Give every stored window its `lm` vector from the loaded frame model
    /// (call with `writes` held): all of them again when the store's were
    /// made by another model (or none were), else only the missing ones.
    /// Returns how many were computed.
    pub(super) async fn backfill_lm(&self) -> Result<usize, QueryError> {
        let emb = self.lm()?.clone();
        let current = self
            .store
            .model("lm")
            .await?
            .is_some_and(|(_, body)| body == emb.fingerprint());
        // The usual case (every window already embedded by this model)
        // costs two counts, not a read of every vector.
        let (_, nwin) = self.store.counts().await?;
        if current && self.store.count_embeddings(Embedding::Lm).await? == nwin {
            self.lm_ready.store(true, Ordering::Release);
            return Ok(0);
        }
        let have: std::collections::HashSet<i64> = if current {
            self.store
                .embeddings(Embedding::Lm)
                .await?
                .into_iter()
                .map(|(id, _)| id)
                .collect()
        } else {
            Default::default()
        };
        let windows = self.store.windows().await?;
        let todo: Vec<(i64, WindowRef)> = windows
            .into_iter()
            .filter(|(id, _)| !have.contains(id))
            .collect();
        if current && todo.is_empty() {
            self.lm_ready.store(true, Ordering::Release);
            return Ok(0);
        }
        let t0 = std::time::Instant::now();
        let channels = self.store.all_channels().await?;
        let rows = tokio::task::spawn_blocking(move || {
            let by_motion: std::collections::HashMap<i64, &Vec<[f32; 72]>> =
                channels.iter().map(|(id, c)| (*id, c)).collect();
            let (ids, wins): (Vec<i64>, Vec<Vec<f32>>) = todo
                .iter()
                .filter_map(|(id, w)| {
                    let ch = by_motion.get(&w.motion_id)?;
                    Some((*id, crate::features::window(ch, w.start_frame as usize)))
                })
                .unzip();
            emb.many(&wins)
                .map(|v| ids.into_iter().zip(v).collect::<Vec<_>>())
        })
        .await
        .map_err(|e| QueryError::Index("lm".into(), format!("worker failed: {e}")))?
        .map_err(|e| QueryError::Index("lm".into(), e.to_string()))?;
        if current {
            self.store.add_embeddings(Embedding::Lm, &rows).await?;
        } else {
            let fp = self.store.windows_fingerprint().await?;
            let body = self.lm()?.fingerprint().to_string();
            self.store
                .replace_embeddings(Embedding::Lm, &rows, "lm", &body, fp)
                .await?;
        }
        // This process's own write: nothing for the replica sync to redo.
        self.synced
            .store(self.store.generation().await?, Ordering::Release);
        tracing::info!(
            "lm embeddings computed for {} stored windows in {:.1} s",
            rows.len(),
            t0.elapsed().as_secs_f64()
        );
        self.lm_ready.store(true, Ordering::Release);
        Ok(rows.len())
    }

    /// The `lm` vectors of one stored motion's windows, computed from its
    /// stored channels and stored (windows that have one keep it).
    async fn lm_for_motion(
        &self,
        id: i64,
        windows: &[(i64, WindowRef)],
    ) -> Result<Vec<(usize, Vec<f32>)>, QueryError> {
        let emb = self.lm()?.clone();
        let Some((_, ch)) = self.store.channel_range(id, 0, 1 << 32).await? else {
            return Ok(Vec::new());
        };
        let w = windows.to_vec();
        let rows = tokio::task::spawn_blocking(move || {
            let wins: Vec<Vec<f32>> = w
                .iter()
                .map(|(_, r)| crate::features::window(&ch, r.start_frame as usize))
                .collect();
            emb.many(&wins)
                .map(|v| w.iter().map(|(id, _)| *id).zip(v).collect::<Vec<_>>())
        })
        .await
        .map_err(|e| QueryError::Index("lm".into(), format!("worker failed: {e}")))?
        .map_err(|e| QueryError::Index("lm".into(), e.to_string()))?;
        self.store.add_embeddings(Embedding::Lm, &rows).await?;
        Ok(rows.into_iter().map(|(i, v)| (i as usize, v)).collect())
    }

    /// Run [`Searcher::sync`] every `every` (a replica's view of writes
    /// made through the others). A store that cannot be reached is logged
    /// once per outage and tried again; the task ends with the searcher.
    pub fn spawn_sync(self: &Arc<Self>, every: std::time::Duration) {
        let me = Arc::downgrade(self);
        tokio::spawn(async move {
            let mut failing = false;
            loop {
                tokio::time::sleep(every).await;
                let Some(s) = me.upgrade() else { break };
                match s.sync().await {
                    Ok(_) if failing => {
                        tracing::info!("store reachable again; replica in sync");
                        failing = false;
                    }
                    Ok(_) => {}
                    Err(err) if !failing => {
                        tracing::warn!("replica sync failed (will retry): {err}");
                        failing = true;
                    }
                    Err(_) => {}
                }
            }
        });
    }

    /// The slow work writes leave behind, one job at a time while queries
    /// go on: refit PCA when [`ingest::pca_due`] (its indexes rebuilt on
    /// the new basis, then swapped in), rebuild indexes past
    /// [`COMPACT_SHARE`] deleted points, and save every changed HNSW dump
    /// (the rest get the store's generation in their meta).
    pub async fn maintain(&self) -> Result<(), QueryError> {
        let _w = self.writes.lock().await;
        if ingest::pca_due(&self.store).await? {
            let fitted = ingest::refit_pca(&self.store).await?;
            self.catalog.write().expect("catalog lock").pca = fitted.map(|(p, _)| Arc::new(p));
            let fit = self.store.model("pca").await?.map_or(-1, |(g, _)| g);
            self.pca_fit.store(fit, Ordering::Release);
            for (key, _) in self
                .built()
                .into_iter()
                .filter(|(k, _)| k.0 == Embedding::Pca)
            {
                let fresh = Arc::new(self.build(key, false).await?);
                self.indexes.lock().expect("index map").insert(key, fresh);
            }
        }
        for (key, entry) in self.built() {
            let dead = entry.dead.load(Ordering::Acquire);
            if dead > 0 && dead as f64 > COMPACT_SHARE * entry.ix.len() as f64 {
                let fresh = Arc::new(self.build(key, false).await?);
                self.indexes.lock().expect("index map").insert(key, fresh);
            }
        }
        let generation = self.store.generation().await?;
        for ((e, m, exact), entry) in self.built() {
            if exact {
                continue;
            }
            let base = self.index_base(e, m);
            let saved = if entry.dirty.swap(false, Ordering::AcqRel) {
                let ix = entry.ix.clone();
                tokio::task::spawn_blocking(move || save_any(&*ix, &base, generation))
                    .await
                    .map_err(|err| QueryError::Index(e.name().into(), err.to_string()))?
            } else {
                HnswIndex::touch(&base, generation)
            };
            if let Err(err) = saved {
                tracing::warn!("index {}-{}: not saved ({err})", e.name(), m.name());
            }
        }
        Ok(())
    }

    /// Run [`Searcher::maintain`] in the background after writes (a quiet
    /// spell of `debounce` first, so a burst of writes costs one job). The
    /// task ends when the searcher is dropped.
    pub fn spawn_maintenance(self: &Arc<Self>, debounce: std::time::Duration) {
        let wake = self.wake.clone();
        let me = Arc::downgrade(self);
        tokio::spawn(async move {
            loop {
                let woke =
                    tokio::time::timeout(std::time::Duration::from_secs(30), wake.notified())
                        .await
                        .is_ok();
                if me.strong_count() == 0 {
                    break;
                }
                if !woke {
                    continue;
                }
                tokio::time::sleep(debounce).await;
                let Some(s) = me.upgrade() else { break };
                if let Err(err) = s.maintain().await {
                    tracing::error!("index maintenance failed: {err}");
                }
            }
        });
    }
}

/// Save an index when it is an HNSW one.
fn save_any(ix: &dyn AnnIndex, base: &std::path::Path, generation: i64) -> anyhow::Result<()> {
    match ix.as_hnsw() {
        Some(h) => h.save(base, generation).map(|_| ()),
        None => Ok(()),
    }
}
