//! Query: the stored windows most like a clip, by one embedding and metric,
//! through the HNSW index (or exact search), optionally filtered by labels.

use crate::features::{
    channels72, window, window_starts, Embedding, Extractor, Pca, StftParams, FEATURE_FPS, WINDOW,
};
use crate::index::hnsw::{HnswIndex, HnswParams};
use crate::index::{AnnIndex, ExactIndex, Hit, Metric};
use crate::motion::{Labels, Motion, MotionError};
use crate::store::{MotionRow, Store, StoreError, WindowRef};
use serde::Serialize;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

#[derive(Debug, thiserror::Error)]
pub enum QueryError {
    #[error(transparent)]
    Motion(#[from] MotionError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("index {0}: {1}")]
    Index(String, String),
}

#[derive(Clone, Debug)]
pub struct QueryRequest {
    pub motion: Motion,
    /// Start of the query segment, seconds from the clip's first frame.
    pub start_s: f64,
    /// Segment length in frames at 60 fps (at least 128; longer segments
    /// query every window in them, hop 32, and keep each hit's best score).
    pub frames: usize,
    pub k: usize,
    pub embedding: Embedding,
    pub metric: Metric,
    /// `kind=value` labels every hit must carry.
    pub filters: Vec<(String, String)>,
    /// Exact search instead of HNSW.
    pub exact: bool,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct QueryHit {
    pub motion_id: i64,
    pub source_path: String,
    pub start_frame: i64,
    pub start_s: f64,
    /// Cosine similarity, or Euclidean distance.
    pub score: f32,
    pub labels: Labels,
}

pub struct Searcher {
    store: Store,
    extractor: Extractor,
    pca: Option<Pca>,
    windows: HashMap<i64, WindowRef>,
    motions: HashMap<i64, MotionRow>,
    generation: i64,
    params: HnswParams,
    indexes: Mutex<HashMap<(Embedding, Metric, bool), Arc<dyn AnnIndex>>>,
}

impl Searcher {
    /// Read the store's window map, motions and PCA basis.
    pub async fn open(store: Store, params: HnswParams) -> Result<Searcher, QueryError> {
        let pca = crate::service::ingest::refresh_pca(&store).await?;
        let windows = store.windows().await?.into_iter().collect();
        let motions = store
            .motions()
            .await?
            .into_iter()
            .map(|m| (m.id, m))
            .collect();
        let generation = store.generation().await?;
        Ok(Searcher {
            store,
            extractor: Extractor::new(StftParams::default())?,
            pca,
            windows,
            motions,
            generation,
            params,
            indexes: Mutex::new(HashMap::new()),
        })
    }

    /// The store generation this searcher reflects.
    pub fn generation(&self) -> i64 {
        self.generation
    }

    pub fn params(&self) -> HnswParams {
        self.params
    }

    pub fn window_count(&self) -> usize {
        self.windows.len()
    }

    fn index_base(&self, e: Embedding, m: Metric) -> PathBuf {
        let mut s = self.store.path().as_os_str().to_owned();
        s.push(format!(".{}-{}", e.name(), m.name()));
        PathBuf::from(s)
    }

    /// The index for an embedding and metric: loaded from disk when current,
    /// rebuilt from the store (and saved) when missing, stale or corrupt.
    pub async fn index(
        &self,
        e: Embedding,
        m: Metric,
        exact: bool,
    ) -> Result<Arc<dyn AnnIndex>, QueryError> {
        if let Some(ix) = self
            .indexes
            .lock()
            .expect("index cache")
            .get(&(e, m, exact))
        {
            return Ok(ix.clone());
        }
        let dim = self.extractor.dim(e);
        let count = self.store.count_embeddings(e).await?;
        let base = self.index_base(e, m);
        let ix: Arc<dyn AnnIndex> = if exact {
            let rows = self.store.embeddings(e).await?;
            let mut ix = ExactIndex::new(m, dim);
            for (id, v) in rows {
                ix.add(id as usize, &v);
            }
            Arc::new(ix)
        } else {
            let generation = self.generation;
            let params = self.params;
            let loaded = {
                let b = base.clone();
                tokio::task::spawn_blocking(move || HnswIndex::load(&b, m, dim, count, generation))
                    .await
                    .map_err(|err| QueryError::Index(base.display().to_string(), err.to_string()))?
            };
            match loaded {
                Ok(Some(mut ix)) => {
                    ix.set_ef_search(params.ef_search);
                    Arc::new(ix)
                }
                other => {
                    if let Err(err) = other {
                        eprintln!(
                            "index {}: unreadable ({err}); rebuilding from the store",
                            base.display()
                        );
                    }
                    let rows = self.store.embeddings(e).await?;
                    let built = tokio::task::spawn_blocking(move || {
                        let items: Vec<(usize, Vec<f32>)> =
                            rows.into_iter().map(|(id, v)| (id as usize, v)).collect();
                        let mut ix = HnswIndex::new(m, dim, items.len(), params);
                        ix.add_batch(&items);
                        let saved = ix
                            .save(&base, generation)
                            .map_err(|err| format!("{}: {err}", base.display()));
                        (ix, saved)
                    })
                    .await
                    .map_err(|err| QueryError::Index(e.name().into(), err.to_string()))?;
                    if let Err(err) = built.1 {
                        eprintln!("index not saved: {err}");
                    }
                    Arc::new(built.0)
                }
            }
        };
        self.indexes
            .lock()
            .expect("index cache")
            .insert((e, m, exact), ix.clone());
        Ok(ix)
    }

    /// The query windows of a request, as embeddings.
    fn query_vectors(&self, req: &QueryRequest) -> Result<Vec<Vec<f32>>, QueryError> {
        let name = req.motion.name.clone();
        req.motion.validate()?;
        if req.k == 0 || req.k > 1000 {
            return Err(
                MotionError::invalid(&name, "k", format!("{} is not in 1..=1000", req.k)).into(),
            );
        }
        if req.frames < WINDOW {
            return Err(MotionError::invalid(
                &name,
                "frames",
                format!(
                    "{} frames is shorter than a {WINDOW}-frame window",
                    req.frames
                ),
            )
            .into());
        }
        if !(req.start_s.is_finite() && req.start_s >= 0.0) {
            return Err(MotionError::invalid(
                &name,
                "start",
                format!("{} s is not a start time", req.start_s),
            )
            .into());
        }
        let ch = channels72(&req.motion)?;
        let start = (req.start_s * FEATURE_FPS).round() as usize;
        if start + req.frames > ch.len() {
            return Err(MotionError::invalid(
                &name,
                "frames",
                format!(
                    "segment {start}..{} (60 fps frames) runs past the clip's {} frames ({:.2} s)",
                    start + req.frames,
                    ch.len(),
                    ch.len() as f64 / FEATURE_FPS
                ),
            )
            .into());
        }
        let seg = &ch[start..start + req.frames];
        window_starts(seg.len(), 32)
            .into_iter()
            .map(|s| {
                self.extractor
                    .embed(req.embedding, &window(seg, s), self.pca.as_ref())
                    .map_err(Into::into)
            })
            .collect()
    }

    pub async fn query(&self, req: &QueryRequest) -> Result<Vec<QueryHit>, QueryError> {
        let vectors = self.query_vectors(req)?;
        let ix = self.index(req.embedding, req.metric, req.exact).await?;
        let allowed: Option<HashSet<i64>> = if req.filters.is_empty() {
            None
        } else {
            Some(
                self.store
                    .motions_with_labels(&req.filters)
                    .await?
                    .into_iter()
                    .collect(),
            )
        };
        let windows = &self.windows;
        let filter = |id: usize| {
            allowed.as_ref().is_none_or(|a| {
                windows
                    .get(&(id as i64))
                    .is_some_and(|w| a.contains(&w.motion_id))
            })
        };
        let k = req.k;
        let mut best: HashMap<usize, f32> = HashMap::new();
        for q in &vectors {
            for Hit { id, distance } in ix.search(
                q,
                k,
                if allowed.is_some() {
                    Some(&filter)
                } else {
                    None
                },
            ) {
                let e = best.entry(id).or_insert(f32::INFINITY);
                *e = e.min(distance);
            }
        }
        let mut hits: Vec<(usize, f32)> = best.into_iter().collect();
        hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        hits.truncate(k);
        Ok(hits
            .into_iter()
            .filter_map(|(id, d)| {
                let w = self.windows.get(&(id as i64))?;
                let m = self.motions.get(&w.motion_id)?;
                Some(QueryHit {
                    motion_id: m.id,
                    source_path: m.source_path.clone(),
                    start_frame: w.start_frame,
                    start_s: w.start_frame as f64 / FEATURE_FPS,
                    score: req.metric.score(d),
                    labels: m.labels.clone(),
                })
            })
            .collect())
    }
}
