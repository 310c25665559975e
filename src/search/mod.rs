//! Query: the stored windows most like a clip, by one embedding and metric,
//! through the HNSW index (or exact search), optionally filtered by labels.
//!
//! The searcher is live. Writes go through it ([`Searcher::ingest`],
//! [`Searcher::delete`]) and reach its indexes at once: an ingest inserts
//! the new windows into every built index, a delete hides its windows from
//! the next query. Anything slower (a PCA refit, compaction of deleted
//! points, saving the dumps) runs later in [`Searcher::maintain`], one job
//! at a time, while the old indexes keep answering. Queries never wait for
//! a write or for maintenance, except the first query of an index not yet
//! built, which builds it. The request checks live in [`request`], the
//! writes and maintenance in [`writes`].

mod channels;
pub mod ingest;
mod request;
mod writes;
pub use channels::DEFAULT_BUDGET_MB as DEFAULT_CHANNEL_CACHE_MB;
pub use writes::IngestOutcome;

use crate::features::{
    channels72, window, window_starts, Embedding, Extractor, Pca, StftParams, FEATURE_FPS,
};
use crate::index::hnsw::{HnswIndex, HnswParams};
use crate::index::{AnnIndex, ExactIndex, Hit, Metric};
use crate::motion::{Labels, Motion, MotionError};

use crate::store::{MotionRow, Store, StoreError, WindowRef};
use serde::Serialize;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, RwLock};

#[derive(Debug, thiserror::Error)]
pub enum QueryError {
    #[error(transparent)]
    Motion(#[from] MotionError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("index {0}: {1}")]
    Index(String, String),
    /// The query names a stored motion that does not exist.
    #[error("no stored motion {0}")]
    NotFound(i64),
}

/// What a query searches with.
#[derive(Clone, Debug)]
pub enum QuerySource {
    /// A clip given whole.
    Motion(Motion),
    /// A stored motion, by id: its stored channels are read (no source
    /// file re-read or parsed), and windows on the stored grid reuse their
    /// stored embeddings.
    Stored(i64),
}

impl From<Motion> for QuerySource {
    fn from(m: Motion) -> Self {
        QuerySource::Motion(m)
    }
}

#[derive(Clone, Debug)]
pub struct QueryRequest {
    pub source: QuerySource,
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
    /// Only motions of these collections may be hits (`None`: any).
    pub collections: Option<Vec<String>>,
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
    /// The footage the hit's motion came from, and the video time of the
    /// matched window's start (absent for motions without footage).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub video: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub video_time_s: Option<f64>,
}

type Key = (Embedding, Metric, bool);

/// One built index and what it was built with.
struct Entry {
    ix: Arc<dyn AnnIndex>,
    /// The PCA basis its vectors were projected on (PCA indexes only).
    pca: Option<Arc<Pca>>,
    /// Points whose windows were deleted since it was built (hidden by the
    /// query filter until compaction).
    dead: AtomicUsize,
    /// Changed since it was last saved.
    dirty: AtomicBool,
}

/// The store's windows and motions as the searcher serves them.
#[derive(Default)]
struct Catalog {
    windows: HashMap<i64, WindowRef>,
    /// Window ids of each motion.
    by_motion: HashMap<i64, Vec<i64>>,
    motions: HashMap<i64, MotionRow>,
    /// The PCA basis new windows are projected on.
    pca: Option<Arc<Pca>>,
}

impl Catalog {
    fn add_motion(&mut self, row: MotionRow, windows: &[(i64, WindowRef)]) {
        self.by_motion
            .insert(row.id, windows.iter().map(|(id, _)| *id).collect());
        for (id, w) in windows {
            self.windows.insert(*id, *w);
        }
        self.motions.insert(row.id, row);
    }
}

/// Stored windows that serve as queries when an index's `ef_search` is
/// chosen, and the recall@10 it must reach against exact search.
pub const CALIBRATION_QUERIES: usize = 100;
pub const TARGET_RECALL: f64 = 0.99;

/// Share of deleted points past which an index is rebuilt by maintenance.
pub const COMPACT_SHARE: f64 = 0.25;

pub struct Searcher {
    store: Store,
    extractor: Extractor,
    params: HnswParams,
    catalog: RwLock<Catalog>,
    indexes: Mutex<HashMap<Key, Arc<Entry>>>,
    /// Serialises writes, index builds and maintenance (never queries).
    writes: tokio::sync::Mutex<()>,
    /// Woken after each write; the maintenance task waits on it.
    wake: Arc<tokio::sync::Notify>,
    /// The store generation the catalog and indexes were last brought up
    /// to date with ([`Searcher::sync`]).
    synced: std::sync::atomic::AtomicI64,
    /// The stored PCA model's fingerprint the catalog's basis came from
    /// (-1: none), so a basis refitted by another process is noticed.
    pca_fit: std::sync::atomic::AtomicI64,
    /// The frame model that gives the `lm` embedding, once the server has
    /// loaded one ([`Searcher::set_lm`]).
    lm: std::sync::OnceLock<crate::lm::embed::LmEmbedder>,
    /// Every stored window has its `lm` vector from that model (set by the
    /// first `lm` index build, [`Searcher::backfill_lm`]); until then
    /// ingests skip the `lm` embedding, so a server whose clients never
    /// ask for it never computes it.
    lm_ready: AtomicBool,
    /// Stored motions' channels kept for queries by id.
    channels: channels::ChannelCache,
}

impl Searcher {
    /// Read the store's window map, motions and PCA basis (refitted first
    /// when [`ingest::pca_due`]).
    pub async fn open(store: Store, params: HnswParams) -> Result<Searcher, QueryError> {
        let generation = store.generation().await?;
        ingest::backfill_pose(&store).await?;
        let pca = if ingest::pca_due(&store).await? {
            ingest::refit_pca(&store).await?.map(|(p, _)| p)
        } else {
            ingest::stored_pca(&store).await?
        };
        let mut catalog = Catalog {
            pca: pca.map(Arc::new),
            ..Default::default()
        };
        for (id, w) in store.windows().await? {
            catalog.windows.insert(id, w);
            catalog.by_motion.entry(w.motion_id).or_default().push(id);
        }
        catalog.motions = store
            .motions()
            .await?
            .into_iter()
            .map(|m| (m.id, m))
            .collect();
        Ok(Searcher {
            extractor: Extractor::new(StftParams::default())?,
            params,
            catalog: RwLock::new(catalog),
            indexes: Mutex::new(HashMap::new()),
            writes: tokio::sync::Mutex::new(()),
            wake: Arc::new(tokio::sync::Notify::new()),
            synced: std::sync::atomic::AtomicI64::new(generation),
            pca_fit: std::sync::atomic::AtomicI64::new(
                store.model("pca").await?.map_or(-1, |(g, _)| g),
            ),
            lm: std::sync::OnceLock::new(),
            lm_ready: AtomicBool::new(false),
            channels: channels::ChannelCache::new(channels::DEFAULT_BUDGET_MB << 20),
            store,
        })
    }

    /// Keep up to this many bytes of stored motions' channels in memory
    /// for queries by stored id (0: read every segment from the store).
    pub fn with_channel_cache(mut self, bytes: usize) -> Searcher {
        self.channels = channels::ChannelCache::new(bytes);
        self
    }

    /// Channel cache (hits, misses, bytes kept).
    pub fn channel_cache_stats(&self) -> (u64, u64, usize) {
        self.channels.stats()
    }

    /// A stored motion's collection and format as the catalog knows them
    /// (both are fixed at ingest), without a database read; `None` when
    /// the catalog has not seen it (a motion another replica just added).
    pub fn motion_access(&self, id: i64) -> Option<(String, String)> {
        self.catalog()
            .motions
            .get(&id)
            .map(|m| (m.collection.clone(), m.format.clone()))
    }

    /// Frames `from..from + frames` of a stored motion's channels (fewer at
    /// its end) and its length, from the channel cache when the catalog
    /// knows the motion and it is small enough to keep whole, else from
    /// the store (that segment's bytes only).
    async fn stored_segment(
        &self,
        id: i64,
        from: usize,
        frames: usize,
    ) -> Result<Option<(usize, Vec<[f32; crate::features::CHANNELS]>)>, QueryError> {
        let known = self.catalog().motions.get(&id).map(|m| {
            (
                m.content_hash.clone(),
                (m.duration_s.max(0.0) * FEATURE_FPS).ceil() as usize + 1,
            )
        });
        let slice = |ch: &[[f32; crate::features::CHANNELS]]| {
            let a = from.min(ch.len());
            (ch.len(), ch[a..(a + frames).min(ch.len())].to_vec())
        };
        match known {
            Some((hash, len)) if self.channels.fits(len) => {
                if let Some(ch) = self.channels.get(id, &hash) {
                    return Ok(Some(slice(&ch)));
                }
                let Some((_, ch)) = self.store.channel_range(id, 0, 1 << 32).await? else {
                    return Ok(None);
                };
                let out = slice(&ch);
                self.channels.put(id, &hash, Arc::new(ch));
                Ok(Some(out))
            }
            _ => Ok(self.store.channel_range(id, from, frames).await?),
        }
    }

    /// Offer the `lm` embedding with this frame model (once; later calls
    /// are ignored).
    pub fn set_lm(&self, embedder: crate::lm::embed::LmEmbedder) {
        let _ = self.lm.set(embedder);
    }

    /// The `lm` embedder, or the request's error when none is loaded.
    fn lm(&self) -> Result<&crate::lm::embed::LmEmbedder, QueryError> {
        self.lm.get().ok_or_else(|| {
            MotionError::invalid(
                "query",
                "embedding",
                "lm is the frame model's embedding: this server has no frame model loaded (choreo serve --model DIR with a motion-frame-lm model)",
            )
            .into()
        })
    }

    /// Dimensions of an embedding's vectors.
    fn dim(&self, e: Embedding) -> usize {
        match (e, self.lm.get()) {
            (Embedding::Lm, Some(l)) => l.dim(),
            _ => self.extractor.dim(e),
        }
    }

    pub fn params(&self) -> HnswParams {
        self.params
    }

    pub fn window_count(&self) -> usize {
        self.catalog().windows.len()
    }

    fn catalog(&self) -> std::sync::RwLockReadGuard<'_, Catalog> {
        self.catalog.read().expect("catalog lock")
    }

    fn index_base(&self, e: Embedding, m: Metric) -> PathBuf {
        let mut s = self.store.path().as_os_str().to_owned();
        s.push(format!(".{}-{}", e.name(), m.name()));
        PathBuf::from(s)
    }

    fn built(&self) -> Vec<(Key, Arc<Entry>)> {
        self.indexes
            .lock()
            .expect("index map")
            .iter()
            .map(|(k, v)| (*k, v.clone()))
            .collect()
    }

    /// The index for an embedding and metric (it may hold deleted windows'
    /// points until maintenance compacts it; queries never see them).
    pub async fn index(
        &self,
        e: Embedding,
        m: Metric,
        exact: bool,
    ) -> Result<Arc<dyn AnnIndex>, QueryError> {
        Ok(self.entry((e, m, exact)).await?.ix.clone())
    }

    /// The index for an embedding and metric, built on first use: loaded
    /// from disk when current, else built from the store and saved.
    async fn entry(&self, key: Key) -> Result<Arc<Entry>, QueryError> {
        if let Some(e) = self.indexes.lock().expect("index map").get(&key) {
            return Ok(e.clone());
        }
        let _w = self.writes.lock().await;
        if let Some(e) = self.indexes.lock().expect("index map").get(&key) {
            return Ok(e.clone());
        }
        let e = Arc::new(self.build(key, true).await?);
        self.indexes
            .lock()
            .expect("index map")
            .insert(key, e.clone());
        Ok(e)
    }

    /// Build one index from the store (call with `writes` held). HNSW
    /// indexes are loaded from their dump when it is current (`load`) and
    /// saved after a build.
    async fn build(&self, (e, m, exact): Key, load: bool) -> Result<Entry, QueryError> {
        if e == Embedding::Lm {
            self.backfill_lm().await?;
        }
        let dim = self.dim(e);
        let live = self.catalog().windows.len();
        let pca = match e {
            Embedding::Pca => self.catalog().pca.clone(),
            _ => None,
        };
        let base = self.index_base(e, m);
        let generation = self.store.generation().await?;
        let params = self.params;
        let fail = |err: String| QueryError::Index(base.display().to_string(), err);
        if !exact && load {
            let b = base.clone();
            let loaded = tokio::task::spawn_blocking(move || {
                HnswIndex::load(&b, m, params.stored_dtype(), dim, live, generation)
            })
            .await
            .map_err(|err| fail(err.to_string()))?;
            match loaded {
                // Built by the other graph, or with another M or
                // ef_construction: rebuilt as configured.
                Ok(Some(ix))
                    if ix.params().backend != params.backend
                        || ix.params().m != params.m
                        || ix.params().ef_construction != params.ef_construction => {}
                Ok(Some(ix)) => {
                    let dead = ix.len().saturating_sub(live);
                    return Ok(Entry {
                        ix: Arc::new(ix),
                        pca,
                        dead: AtomicUsize::new(dead),
                        dirty: AtomicBool::new(false),
                    });
                }
                Ok(None) => {}
                Err(err) => tracing::warn!(
                    "index {}: unreadable ({err}); rebuilding from the store",
                    base.display()
                ),
            }
        }
        let rows = self.store.embeddings(e).await?;
        let b = base.clone();
        let ix: Arc<dyn AnnIndex> = tokio::task::spawn_blocking(move || {
            let items: Vec<(usize, Vec<f32>)> =
                rows.into_iter().map(|(id, v)| (id as usize, v)).collect();
            if exact {
                let ix = ExactIndex::new(m, dim);
                for (id, v) in &items {
                    ix.add(*id, v);
                }
                return Arc::new(ix) as Arc<dyn AnnIndex>;
            }
            // ef_search for recall@10 ≥ 0.99 on held-out stored windows.
            let ix = HnswIndex::build_calibrated(
                m,
                dim,
                params,
                &items,
                CALIBRATION_QUERIES,
                TARGET_RECALL,
            );
            if let Err(err) = ix.save(&b, generation) {
                tracing::warn!("index {} not saved: {err}", b.display());
            }
            Arc::new(ix)
        })
        .await
        .map_err(|err| fail(err.to_string()))?;
        Ok(Entry {
            ix,
            pca,
            dead: AtomicUsize::new(0),
            dirty: AtomicBool::new(false),
        })
    }

    /// The query windows of a request, as embeddings (CPU work: call on a
    /// blocking thread). `reuse[i]` is a stored embedding for window `i`.
    fn query_vectors(
        &self,
        req: &QueryRequest,
        ch: &[[f32; crate::features::CHANNELS]],
        start: usize,
        pca: Option<&Pca>,
        reuse: &HashMap<usize, Vec<f32>>,
    ) -> Result<Vec<Vec<f32>>, QueryError> {
        let seg = &ch[start..start + req.frames];
        window_starts(seg.len(), 32)
            .into_iter()
            .map(|s| match reuse.get(&s) {
                Some(v) => Ok(v.clone()),
                None if req.embedding == Embedding::Lm => self
                    .lm()?
                    .window(&window(seg, s))
                    .map_err(|e| QueryError::Index("lm".into(), e.to_string())),
                None => self
                    .extractor
                    .embed(req.embedding, &window(seg, s), pca)
                    .map_err(Into::into),
            })
            .collect()
    }

    pub async fn query(self: &Arc<Self>, req: QueryRequest) -> Result<Vec<QueryHit>, QueryError> {
        if req.embedding == Embedding::Lm {
            self.lm()?;
        }
        let entry = self.entry((req.embedding, req.metric, req.exact)).await?;
        // Motions of the collections the caller may see (`None`: all).
        let visible: Option<HashSet<i64>> = req.collections.as_ref().map(|cs| {
            self.catalog()
                .motions
                .values()
                .filter(|m| cs.contains(&m.collection))
                .map(|m| m.id)
                .collect()
        });
        let mut allowed: Option<HashSet<i64>> = if req.filters.is_empty() {
            None
        } else {
            self.check_filters(&req.filters, visible.as_ref()).await?;
            Some(
                self.store
                    .motions_with_labels(&req.filters)
                    .await?
                    .into_iter()
                    .collect(),
            )
        };
        if let Some(v) = visible {
            allowed = Some(match allowed {
                Some(a) => a.intersection(&v).copied().collect(),
                None => v,
            });
        }
        let (stored, reuse) = match &req.source {
            QuerySource::Stored(id) => {
                // Only the segment's frames are read from the store.
                let from = if req.start_s.is_finite() && req.start_s >= 0.0 {
                    (req.start_s * FEATURE_FPS).round() as usize
                } else {
                    0
                };
                let (total, seg) = self
                    .stored_segment(*id, from, req.frames)
                    .await?
                    .ok_or(QueryError::NotFound(*id))?;
                let start = self.segment(&req, &format!("motion {id}"), total)?;
                let reuse = self.reusable(&req, *id, start).await?;
                (Some((seg, 0)), reuse)
            }
            QuerySource::Motion(_) => (None, HashMap::new()),
        };
        let me = self.clone();
        let name = req_name(&req);
        tokio::task::spawn_blocking(move || {
            let (ch, start) = match (stored, &req.source) {
                (Some(s), _) => s,
                (None, QuerySource::Motion(m)) => {
                    m.validate()?;
                    let ch = channels72(m)?;
                    let start = me.segment(&req, &m.name, ch.len())?;
                    (ch, start)
                }
                (None, QuerySource::Stored(id)) => return Err(QueryError::NotFound(*id)),
            };
            let vectors = me.query_vectors(&req, &ch, start, entry.pca.as_deref(), &reuse)?;
            Ok(me.search(&req, &entry, &vectors, allowed.as_ref()))
        })
        .await
        .map_err(|err| QueryError::Index(name, err.to_string()))?
    }

    /// Search every query vector, keep each window's best distance, and
    /// give the `k` best as hits (deleted windows and filtered motions are
    /// never seen).
    fn search(
        &self,
        req: &QueryRequest,
        entry: &Entry,
        vectors: &[Vec<f32>],
        allowed: Option<&HashSet<i64>>,
    ) -> Vec<QueryHit> {
        let catalog = self.catalog();
        let windows = &catalog.windows;
        let filter = |id: usize| {
            windows
                .get(&(id as i64))
                .is_some_and(|w| allowed.is_none_or(|a| a.contains(&w.motion_id)))
        };
        let filtered = allowed.is_some() || entry.dead.load(Ordering::Acquire) > 0;
        let mut best: HashMap<usize, f32> = HashMap::new();
        for q in vectors {
            let f: Option<&(dyn Fn(usize) -> bool + Sync)> =
                if filtered { Some(&filter) } else { None };
            for Hit { id, distance } in entry.ix.search(q, req.k, f) {
                let e = best.entry(id).or_insert(f32::INFINITY);
                *e = e.min(distance);
            }
        }
        let mut hits: Vec<(usize, f32)> = best.into_iter().collect();
        hits.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        hits.truncate(req.k);
        hits.into_iter()
            .filter_map(|(id, d)| {
                let w = windows.get(&(id as i64))?;
                let m = catalog.motions.get(&w.motion_id)?;
                Some(QueryHit {
                    motion_id: m.id,
                    source_path: m.source_path.clone(),
                    start_frame: w.start_frame,
                    start_s: w.start_frame as f64 / FEATURE_FPS,
                    score: req.metric.score(d),
                    labels: m.labels.clone(),
                    video: m.video.as_ref().map(|v| v.video.clone()),
                    video_time_s: m
                        .video
                        .as_ref()
                        .map(|v| v.video_offset_s + w.start_frame as f64 / FEATURE_FPS),
                })
            })
            .collect()
    }
}

fn req_name(req: &QueryRequest) -> String {
    match &req.source {
        QuerySource::Motion(m) => m.name.clone(),
        QuerySource::Stored(id) => format!("motion {id}"),
    }
}
