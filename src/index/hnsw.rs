//! HNSW through hnsw_rs, persisted as its two dump files
//! (`BASE.hnsw.graph`, `BASE.hnsw.data`) plus `BASE.meta.json`, which records
//! what the dump was built from so a stale or corrupt index is rebuilt.

use super::{AnnIndex, Hit, Metric, VectorDtype};
use hnsw_rs::prelude::{AnnT, Distance, FilterT, Hnsw, HnswIo};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Cosine on L2-normalised vectors: `1 − a·b`, clamped at 0.
#[derive(Default, Clone, Copy)]
pub struct CosineUnit;
impl Distance<f32> for CosineUnit {
    fn eval(&self, va: &[f32], vb: &[f32]) -> f32 {
        (1.0 - super::dot(va, vb)).max(0.0)
    }
}

/// Euclidean distance.
#[derive(Default, Clone, Copy)]
pub struct Euclid;
impl Distance<f32> for Euclid {
    fn eval(&self, va: &[f32], vb: &[f32]) -> f32 {
        super::l2(va, vb)
    }
}

/// Build parameters.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct HnswParams {
    /// Links per node (M).
    pub m: usize,
    pub ef_construction: usize,
    /// Candidate list size at query time (at least k).
    pub ef_search: usize,
    /// Which graph implementation holds the points.
    #[serde(default)]
    pub backend: Backend,
    /// How the points are stored (f16 only with the flat graph).
    #[serde(default)]
    pub dtype: VectorDtype,
}

/// The HNSW graph behind an [`HnswIndex`].
/// (A meta without one was written by hnsw_rs, the only graph then; new
/// indexes default to the flat graph, [`HnswParams::default`].)
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// hnsw_rs 0.3 (the design card's; parallel build).
    #[default]
    #[value(name = "hnsw_rs")]
    HnswRs,
    /// choreo's flat-array HNSW ([`super::flat`]).
    Flat,
}

impl Backend {
    pub fn parse(s: &str) -> Option<Backend> {
        match s {
            "hnsw_rs" | "hnsw-rs" => Some(Backend::HnswRs),
            "flat" => Some(Backend::Flat),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Backend::HnswRs => "hnsw_rs",
            Backend::Flat => "flat",
        }
    }
}

impl HnswParams {
    /// The vector type an index built with these params stores (hnsw_rs:
    /// always f32).
    pub fn stored_dtype(&self) -> VectorDtype {
        match self.backend {
            Backend::HnswRs => VectorDtype::F32,
            Backend::Flat => self.dtype,
        }
    }
}

impl Default for HnswParams {
    fn default() -> Self {
        HnswParams {
            // 16 links (32 at level 0): on the 5,972 stored STFT windows the
            // calibrated graph answered 2,061 queries/s under load against
            // 1,885 with 24, each at recall@10 >= 0.99 (bench/RESULTS.md).
            m: 16,
            ef_construction: 200,
            ef_search: 128,
            backend: Backend::Flat,
            dtype: VectorDtype::F32,
        }
    }
}

type CosGraph<'a> = Hnsw<'a, f32, CosineUnit>;
type L2Graph<'a> = Hnsw<'a, f32, Euclid>;

self_cell::self_cell!(
    struct LoadedCos {
        owner: HnswIo,
        #[not_covariant]
        dependent: CosGraph,
    }
);
self_cell::self_cell!(
    struct LoadedL2 {
        owner: HnswIo,
        #[not_covariant]
        dependent: L2Graph,
    }
);

enum Graph {
    Flat(super::flat::FlatGraph),
    Cos(CosGraph<'static>),
    L2(L2Graph<'static>),
    LoadedCos(LoadedCos),
    LoadedL2(LoadedL2),
}

/// What a persisted index was built from.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct IndexMeta {
    pub metric: Metric,
    pub dim: usize,
    pub count: usize,
    /// The store's generation when built; any other value means stale.
    pub generation: i64,
    pub params: HnswParams,
    /// The basename hnsw_rs wrote (it may add a suffix).
    pub dump_basename: String,
    /// Recall@10 at `params.ef_search`, measured when it was calibrated.
    #[serde(default)]
    pub recall_at_10: Option<f64>,
}

pub struct HnswIndex {
    metric: Metric,
    dim: usize,
    /// Points in the graph (deleted ones included: hnsw_rs cannot remove a
    /// point; the caller's filter hides them until a rebuild).
    count: AtomicUsize,
    params: HnswParams,
    /// Recall@10 at `params.ef_search` from [`HnswIndex::calibrate`].
    recall_at_10: Option<f64>,
    graph: Graph,
}

impl HnswIndex {
    /// An empty index. hnsw_rs stores f32 only: with that backend the
    /// params' `dtype` is set to f32 (callers refuse f16 there first).
    pub fn new(metric: Metric, dim: usize, capacity: usize, mut params: HnswParams) -> Self {
        let max_layer = 16;
        let cap = capacity.max(1);
        params.dtype = params.stored_dtype();
        let graph = match metric {
            _ if params.backend == Backend::Flat => Graph::Flat(super::flat::FlatGraph::new(
                metric,
                params.dtype,
                dim,
                params.m,
                params.ef_construction,
            )),
            Metric::Cosine => Graph::Cos(Hnsw::new(
                params.m,
                cap,
                max_layer,
                params.ef_construction,
                CosineUnit,
            )),
            Metric::Euclidean => Graph::L2(Hnsw::new(
                params.m,
                cap,
                max_layer,
                params.ef_construction,
                Euclid,
            )),
        };
        HnswIndex {
            metric,
            dim,
            count: AtomicUsize::new(0),
            params,
            recall_at_10: None,
            graph,
        }
    }

    pub fn params(&self) -> HnswParams {
        self.params
    }
    pub fn set_ef_search(&mut self, ef: usize) {
        self.params.ef_search = ef.max(1);
    }

    /// Recall@10 at the current `ef_search`, when calibrated.
    pub fn recall_at_10(&self) -> Option<f64> {
        self.recall_at_10
    }

    /// Build over `items` with `ef_search` chosen for a target recall:
    /// up to `sample` of the items (evenly spaced) are held out, the rest
    /// inserted, the held-out ones used as queries by [`HnswIndex::calibrate`]
    /// (unseen points, as a user's new clip is), and then inserted too.
    /// Returns the index with its measured (ef, recall).
    pub fn build_calibrated(
        metric: Metric,
        dim: usize,
        params: HnswParams,
        items: &[(usize, Vec<f32>)],
        sample: usize,
        target: f64,
    ) -> HnswIndex {
        let mut ix = HnswIndex::new(metric, dim, items.len(), params);
        let step = (items.len() / sample.max(1)).max(2);
        if items.len() < 4 * sample.max(1) || sample == 0 {
            ix.add_batch(items);
            return ix;
        }
        let (held, rest): (Vec<_>, Vec<_>) = items
            .iter()
            .enumerate()
            .partition(|(i, _)| i % step == step / 2);
        let rest: Vec<(usize, Vec<f32>)> = rest.into_iter().map(|(_, x)| x.clone()).collect();
        let held: Vec<(usize, Vec<f32>)> = held.into_iter().map(|(_, x)| x.clone()).collect();
        ix.add_batch(&rest);
        let queries: Vec<Vec<f32>> = held.iter().map(|(_, v)| v.clone()).collect();
        ix.calibrate(&queries, &rest, target);
        ix.add_batch(&held);
        ix
    }

    /// Choose `ef_search`: the smallest on a ladder (10 … 1,024) whose mean
    /// recall@10 for `queries` against exact search over `indexed` (what
    /// the graph holds now) reaches `target`. Returns (ef, recall); when no
    /// ef reaches the target the largest is kept.
    pub fn calibrate(
        &mut self,
        queries: &[Vec<f32>],
        indexed: &[(usize, Vec<f32>)],
        target: f64,
    ) -> (usize, f64) {
        let k = 10.min(indexed.len());
        if k == 0 || queries.is_empty() {
            return (self.params.ef_search, 1.0);
        }
        let truth = exact_neighbours(self.metric, indexed, queries, k);
        let ladder = [
            10, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512, 768, 1024,
        ];
        let mut chosen = (ladder[ladder.len() - 1], 0.0);
        for ef in ladder {
            self.params.ef_search = ef;
            let r: f64 = queries
                .iter()
                .zip(&truth)
                .map(|(q, t)| super::recall(t, &self.search(q, k, None)))
                .sum::<f64>()
                / queries.len() as f64;
            chosen = (ef, r);
            if r >= target {
                break;
            }
        }
        self.params.ef_search = chosen.0;
        self.recall_at_10 = Some(chosen.1);
        chosen
    }

    /// Insert many raw vectors at once, using every core. Searches may run
    /// meanwhile (hnsw_rs locks each neighbour list, not the graph).
    pub fn add_batch(&self, items: &[(usize, Vec<f32>)]) {
        let prepared: Vec<(Vec<f32>, usize)> = items
            .iter()
            .map(|(id, v)| (self.metric.prepare(v), *id))
            .collect();
        let refs: Vec<(&Vec<f32>, usize)> = prepared.iter().map(|(v, id)| (v, *id)).collect();
        match &self.graph {
            Graph::Flat(f) => {
                let items: Vec<(usize, &[f32])> =
                    refs.iter().map(|(v, id)| (*id, v.as_slice())).collect();
                f.insert_many(&items)
            }
            Graph::Cos(h) => h.parallel_insert(&refs),
            Graph::L2(h) => h.parallel_insert(&refs),
            Graph::LoadedCos(h) => h.with_dependent(|_, g| g.parallel_insert(&refs)),
            Graph::LoadedL2(h) => h.with_dependent(|_, g| g.parallel_insert(&refs)),
        }
        self.count.fetch_add(items.len(), Ordering::Release);
    }

    /// Write the dump beside `base` (a path without extension) under a name
    /// of its own (`STEM-gGENERATION`), then its meta (renamed into place),
    /// then remove the dump the old meta named: a crash at any point leaves
    /// a meta naming a whole dump. The caller keeps inserts out meanwhile.
    pub fn save(&self, base: &Path, generation: i64) -> anyhow::Result<IndexMeta> {
        let dir = base.parent().unwrap_or(Path::new("."));
        let stem = base.file_name().and_then(|s| s.to_str()).unwrap_or("index");
        let old: Option<IndexMeta> = std::fs::read(meta_path(base))
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok());
        let name = format!("{stem}-g{generation}");
        for ext in ["hnsw.graph", "hnsw.data"] {
            let _ = std::fs::remove_file(dir.join(format!("{name}.{ext}")));
        }
        let dumped = match &self.graph {
            Graph::Flat(f) => {
                f.save(&dir.join(format!("{name}.flat")))?;
                name.clone()
            }
            Graph::Cos(h) => h.file_dump(dir, &name)?,
            Graph::L2(h) => h.file_dump(dir, &name)?,
            Graph::LoadedCos(h) => h.with_dependent(|_, g| g.file_dump(dir, &name))?,
            Graph::LoadedL2(h) => h.with_dependent(|_, g| g.file_dump(dir, &name))?,
        };
        let meta = IndexMeta {
            metric: self.metric,
            dim: self.dim,
            count: self.len(),
            generation,
            params: self.params,
            dump_basename: dumped.clone(),
            recall_at_10: self.recall_at_10,
        };
        let tmp = meta_path(base).with_extension("json.partial");
        std::fs::write(&tmp, serde_json::to_vec_pretty(&meta)?)?;
        std::fs::rename(&tmp, meta_path(base))?;
        if let Some(old) = old.filter(|o| o.dump_basename != dumped) {
            // Only files this index wrote (its own stem), never anything else.
            if old.dump_basename.starts_with(stem) {
                for ext in ["hnsw.graph", "hnsw.data", "flat"] {
                    let _ = std::fs::remove_file(dir.join(format!("{}.{ext}", old.dump_basename)));
                }
            }
        }
        Ok(meta)
    }

    /// Record a new store generation in the meta without rewriting the dump
    /// (the graph did not change, the store moved on for other reasons).
    pub fn touch(base: &Path, generation: i64) -> anyhow::Result<()> {
        let mut meta: IndexMeta = serde_json::from_slice(&std::fs::read(meta_path(base))?)?;
        meta.generation = generation;
        let tmp = meta_path(base).with_extension("json.partial");
        std::fs::write(&tmp, serde_json::to_vec_pretty(&meta)?)?;
        std::fs::rename(&tmp, meta_path(base))?;
        Ok(())
    }

    /// Load a dump if its meta says it matches `metric`, `dtype`, `dim`,
    /// `count` and `generation`; `Ok(None)` when missing or stale (another
    /// vector type is stale: the caller rebuilds), `Err` when corrupt.
    pub fn load(
        base: &Path,
        metric: Metric,
        dtype: VectorDtype,
        dim: usize,
        count: usize,
        generation: i64,
    ) -> anyhow::Result<Option<Self>> {
        let Ok(bytes) = std::fs::read(meta_path(base)) else {
            return Ok(None);
        };
        let meta: IndexMeta = serde_json::from_slice(&bytes)?;
        if meta.metric != metric
            || meta.dim != dim
            || meta.count < count
            || meta.generation != generation
            || meta.params.dtype != dtype
        {
            return Ok(None);
        }
        let dir = base.parent().unwrap_or(Path::new(".")).to_path_buf();
        if meta.params.backend == Backend::Flat {
            let f = super::flat::FlatGraph::load(
                &dir.join(format!("{}.flat", meta.dump_basename)),
                metric,
                dtype,
                dim,
            )?;
            if f.len() != meta.count {
                anyhow::bail!(
                    "index dump holds {} points, its meta says {}",
                    f.len(),
                    meta.count
                );
            }
            return Ok(Some(HnswIndex {
                metric,
                dim,
                count: AtomicUsize::new(meta.count),
                params: meta.params,
                recall_at_10: meta.recall_at_10,
                graph: Graph::Flat(f),
            }));
        }
        let io = HnswIo::new(&dir, &meta.dump_basename);
        // hnsw_rs unwraps on some corrupt dumps; a panic here means "corrupt".
        let graph =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| -> anyhow::Result<Graph> {
                Ok(match metric {
                    Metric::Cosine => Graph::LoadedCos(LoadedCos::try_new(io, |io| {
                        io.load_hnsw_with_dist(CosineUnit)
                    })?),
                    Metric::Euclidean => {
                        Graph::LoadedL2(LoadedL2::try_new(io, |io| io.load_hnsw_with_dist(Euclid))?)
                    }
                })
            }))
            .map_err(|_| {
                anyhow::anyhow!(
                    "index dump {} is corrupt (hnsw_rs could not read it)",
                    meta.dump_basename
                )
            })??;
        let ix = HnswIndex {
            metric,
            dim,
            count: AtomicUsize::new(meta.count),
            params: meta.params,
            recall_at_10: meta.recall_at_10,
            graph,
        };
        let n = match &ix.graph {
            Graph::LoadedCos(h) => h.with_dependent(|_, g| g.get_nb_point()),
            Graph::LoadedL2(h) => h.with_dependent(|_, g| g.get_nb_point()),
            _ => 0,
        };
        if n != meta.count {
            anyhow::bail!("index dump holds {n} points, its meta says {}", meta.count);
        }
        Ok(Some(ix))
    }
}

/// The exact `k` nearest of each query among `items`, on every core.
fn exact_neighbours(
    metric: Metric,
    items: &[(usize, Vec<f32>)],
    queries: &[Vec<f32>],
    k: usize,
) -> Vec<Vec<Hit>> {
    let prepared: Vec<Vec<f32>> = queries.iter().map(|q| metric.prepare(q)).collect();
    let norms: Vec<f32> = match metric {
        Metric::Cosine => items.iter().map(|(_, v)| super::dot(v, v).sqrt()).collect(),
        Metric::Euclidean => Vec::new(),
    };
    let one = |q: &Vec<f32>| -> Vec<Hit> {
        let mut top = Vec::with_capacity(k + 1);
        for (i, (id, v)) in items.iter().enumerate() {
            let distance = match metric {
                Metric::Cosine => 1.0 - super::dot(q, v) / norms[i].max(f32::MIN_POSITIVE),
                Metric::Euclidean => super::l2(q, v),
            };
            super::push_top(&mut top, Hit { id: *id, distance }, k);
        }
        top
    };
    let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
    let chunk = prepared.len().div_ceil(threads).max(1);
    std::thread::scope(|s| {
        let handles: Vec<_> = prepared
            .chunks(chunk)
            .map(|c| s.spawn(move || c.iter().map(one).collect::<Vec<_>>()))
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("exact search thread"))
            .collect()
    })
}

pub fn meta_path(base: &Path) -> PathBuf {
    let mut s = base.as_os_str().to_owned();
    s.push(".meta.json");
    PathBuf::from(s)
}

struct FilterFn<'a>(&'a (dyn Fn(usize) -> bool + Sync));
impl FilterT for FilterFn<'_> {
    fn hnsw_filter(&self, id: &usize) -> bool {
        (self.0)(*id)
    }
}

impl AnnIndex for HnswIndex {
    fn metric(&self) -> Metric {
        self.metric
    }
    fn dim(&self) -> usize {
        self.dim
    }
    fn len(&self) -> usize {
        self.count.load(Ordering::Acquire)
    }
    fn add(&self, id: usize, v: &[f32]) {
        self.add_batch(&[(id, v.to_vec())]);
    }
    fn add_batch(&self, items: &[(usize, Vec<f32>)]) {
        HnswIndex::add_batch(self, items)
    }
    fn as_hnsw(&self) -> Option<&HnswIndex> {
        Some(self)
    }
    fn search(
        &self,
        q: &[f32],
        k: usize,
        filter: Option<&(dyn Fn(usize) -> bool + Sync)>,
    ) -> Vec<Hit> {
        if k == 0 || self.len() == 0 {
            return Vec::new();
        }
        let q = self.metric.prepare(q);
        let ef = self.params.ef_search.max(k);
        let f = filter.map(FilterFn);
        let fref: Option<&dyn FilterT> = f.as_ref().map(|f| f as &dyn FilterT);
        let res = match &self.graph {
            Graph::Flat(f) => return f.search(&q, k, ef, filter),
            Graph::Cos(h) => h.search_filter(&q, k, ef, fref),
            Graph::L2(h) => h.search_filter(&q, k, ef, fref),
            Graph::LoadedCos(h) => h.with_dependent(|_, g| g.search_filter(&q, k, ef, fref)),
            Graph::LoadedL2(h) => h.with_dependent(|_, g| g.search_filter(&q, k, ef, fref)),
        };
        let mut hits: Vec<Hit> = res
            .into_iter()
            .map(|n| Hit {
                id: n.d_id,
                distance: n.distance,
            })
            .collect();
        hits.sort_by(|a, b| a.distance.total_cmp(&b.distance));
        hits
    }
}

#[cfg(test)]
mod tests;
