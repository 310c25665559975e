//! Nearest-neighbour indexes over window embeddings: an exact one (the test
//! oracle) and HNSW (hnsw_rs), behind one trait, for cosine or Euclidean
//! similarity.
//!
//! Cosine vectors are L2-normalised on the way in, so cosine distance is
//! `1 − a·b` and the reported score is the cosine similarity. Euclidean
//! scores are distances (smaller is closer).

pub mod flat;
pub mod hnsw;
pub mod kernels;

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Metric {
    Cosine,
    Euclidean,
}

impl Metric {
    pub const ALL: [Metric; 2] = [Metric::Cosine, Metric::Euclidean];
    pub fn name(self) -> &'static str {
        match self {
            Metric::Cosine => "cosine",
            Metric::Euclidean => "euclidean",
        }
    }
    pub fn parse(s: &str) -> Option<Metric> {
        match s.to_ascii_lowercase().as_str() {
            "cosine" => Some(Metric::Cosine),
            "euclidean" | "l2" => Some(Metric::Euclidean),
            _ => None,
        }
    }
    /// The vector as the index stores it (normalised for cosine).
    pub fn prepare(self, v: &[f32]) -> Vec<f32> {
        match self {
            Metric::Cosine => normalized(v),
            Metric::Euclidean => v.to_vec(),
        }
    }
    /// Distance between prepared vectors (smaller is closer).
    pub fn distance(self, a: &[f32], b: &[f32]) -> f32 {
        match self {
            Metric::Cosine => 1.0 - dot(a, b),
            Metric::Euclidean => l2(a, b),
        }
    }
    /// The user-facing score of a distance: cosine similarity, or the
    /// Euclidean distance itself.
    pub fn score(self, distance: f32) -> f32 {
        match self {
            Metric::Cosine => 1.0 - distance,
            Metric::Euclidean => distance,
        }
    }
}

/// How an index stores its vectors: f32; IEEE half floats (half the
/// memory and memory traffic; queries stay f32, so only the stored side is
/// rounded, to a relative 2⁻¹¹); or half floats for the graph walk with
/// the f32 vectors kept beside them to re-score the final candidates
/// exactly (`f16-refine`: the walk's memory traffic halved, 1.5× the
/// memory, exact scores). Half floats are for the flat graph.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum VectorDtype {
    #[default]
    F32,
    F16,
    #[serde(rename = "f16-refine")]
    #[value(name = "f16-refine")]
    F16Refine,
}

impl VectorDtype {
    pub fn name(self) -> &'static str {
        match self {
            VectorDtype::F32 => "f32",
            VectorDtype::F16 => "f16",
            VectorDtype::F16Refine => "f16-refine",
        }
    }

    /// Whether the graph walks half floats.
    pub fn is_half(self) -> bool {
        self != VectorDtype::F32
    }
}

/// Dot product (the run-time-chosen SIMD kernel, [`kernels`]).
#[inline]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    kernels::dot(a, b)
}

/// Euclidean distance (the run-time-chosen SIMD kernel, [`kernels`]).
#[inline]
pub fn l2(a: &[f32], b: &[f32]) -> f32 {
    kernels::l2sq(a, b).sqrt()
}

pub fn normalized(v: &[f32]) -> Vec<f32> {
    let n = dot(v, v).sqrt();
    if n > 0.0 && n.is_finite() {
        v.iter().map(|x| x / n).collect()
    } else {
        v.to_vec()
    }
}

/// One search result: the caller's id and the distance (smaller is closer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub id: usize,
    pub distance: f32,
}

/// What every index offers. Ids are the caller's (window ids).
pub trait AnnIndex: Send + Sync {
    fn metric(&self) -> Metric;
    fn dim(&self) -> usize;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Insert a raw (unprepared) vector. Takes `&self`: a live index takes
    /// inserts while it answers queries.
    fn add(&self, id: usize, v: &[f32]);
    /// Insert many raw vectors (an index may do it faster than one by one).
    fn add_batch(&self, items: &[(usize, Vec<f32>)]) {
        for (id, v) in items {
            self.add(*id, v);
        }
    }
    /// The HNSW index behind this one, if it is one (to save it).
    fn as_hnsw(&self) -> Option<&hnsw::HnswIndex> {
        None
    }
    /// The `k` nearest to a raw query among ids passing `filter`, closest first.
    fn search(
        &self,
        q: &[f32],
        k: usize,
        filter: Option<&(dyn Fn(usize) -> bool + Sync)>,
    ) -> Vec<Hit>;
}

/// Brute force: exact, the oracle for HNSW.
pub struct ExactIndex {
    metric: Metric,
    dim: usize,
    rows: std::sync::RwLock<ExactRows>,
}

#[derive(Default)]
struct ExactRows {
    ids: Vec<usize>,
    data: Vec<f32>,
}

impl ExactIndex {
    pub fn new(metric: Metric, dim: usize) -> Self {
        ExactIndex {
            metric,
            dim,
            rows: Default::default(),
        }
    }
}

impl AnnIndex for ExactIndex {
    fn metric(&self) -> Metric {
        self.metric
    }
    fn dim(&self) -> usize {
        self.dim
    }
    fn len(&self) -> usize {
        self.rows.read().expect("exact index").ids.len()
    }
    fn add(&self, id: usize, v: &[f32]) {
        assert_eq!(v.len(), self.dim, "vector dimension");
        let v = self.metric.prepare(v);
        let mut rows = self.rows.write().expect("exact index");
        rows.ids.push(id);
        rows.data.extend(v);
    }
    fn search(
        &self,
        q: &[f32],
        k: usize,
        filter: Option<&(dyn Fn(usize) -> bool + Sync)>,
    ) -> Vec<Hit> {
        let q = self.metric.prepare(q);
        let rows = self.rows.read().expect("exact index");
        let mut top: Vec<Hit> = Vec::with_capacity(k + 1);
        for (i, &id) in rows.ids.iter().enumerate() {
            if let Some(f) = filter {
                if !f(id) {
                    continue;
                }
            }
            let d = self
                .metric
                .distance(&q, &rows.data[i * self.dim..(i + 1) * self.dim]);
            push_top(&mut top, Hit { id, distance: d }, k);
        }
        top
    }
}

/// Keep `top` sorted ascending with at most `k` entries.
pub fn push_top(top: &mut Vec<Hit>, h: Hit, k: usize) {
    if k == 0 || (top.len() == k && h.distance >= top[k - 1].distance) {
        return;
    }
    let pos = top.partition_point(|x| x.distance <= h.distance);
    top.insert(pos, h);
    top.truncate(k);
}

/// Synthetic benchmark vectors: points on a 16-dimensional latent space (as
/// spectral embeddings of motion are: a few smooth degrees of freedom) lifted
/// linearly to `dim`, plus uniform noise of ±0.05. Seeded, reproducible.
pub fn synthetic_latent(n: usize, dim: usize, seed: u64) -> Vec<Vec<f32>> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(1234);
    let lift: Vec<f32> = (0..16 * dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let z: Vec<f32> = (0..16).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let mut v = vec![0f32; dim];
            for (k, zk) in z.iter().enumerate() {
                for (d, x) in v.iter_mut().enumerate() {
                    *x += zk * lift[k * dim + d];
                }
            }
            v.iter_mut().for_each(|x| *x += rng.gen_range(-0.05..0.05));
            v
        })
        .collect()
}

/// Recall@k of `approx` against `exact` (fraction of exact ids found).
pub fn recall(exact: &[Hit], approx: &[Hit]) -> f64 {
    if exact.is_empty() {
        return 1.0;
    }
    let found = exact
        .iter()
        .filter(|e| approx.iter().any(|a| a.id == e.id))
        .count();
    found as f64 / exact.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_search_by_hand() {
        let ix = ExactIndex::new(Metric::Euclidean, 2);
        ix.add(10, &[0.0, 0.0]);
        ix.add(11, &[1.0, 0.0]);
        ix.add(12, &[5.0, 5.0]);
        let h = ix.search(&[0.9, 0.1], 2, None);
        assert_eq!(h.iter().map(|h| h.id).collect::<Vec<_>>(), vec![11, 10]);
        let only_far = |id: usize| id == 12;
        let h = ix.search(&[0.9, 0.1], 2, Some(&only_far));
        assert_eq!(h.len(), 1);
        assert_eq!(h[0].id, 12);
        let c = ExactIndex::new(Metric::Cosine, 2);
        c.add(1, &[2.0, 0.0]);
        c.add(2, &[0.0, 3.0]);
        let h = c.search(&[1.0, 0.1], 1, None);
        assert_eq!(h[0].id, 1);
        assert!((Metric::Cosine.score(h[0].distance) - 0.995037).abs() < 1e-5);
    }
}
