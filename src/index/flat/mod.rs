//! HNSW on flat arrays (Malkov & Yashunin, 2018): the vectors in one
//! contiguous `n × dim` block (f32, or half floats: [`VectorDtype`]),
//! layer-0 links in one `n × 2M` block of `u32`, upper-layer links per
//! node, a visited set stamped with a search counter instead of cleared.
//! No per-point allocation, no `Arc` or lock per node: a search reads
//! arrays. A single insert takes the graph's write lock (searches hold the
//! read lock), which suits the live searcher's few inserts per write; a
//! bulk build inserts in batches on every core ([`build`]).
//!
//! Distances: cosine is `1 − a·b` on unit vectors, Euclidean is the
//! squared distance inside the graph (same order) and its square root
//! outside. Queries and inserted points stay f32; only the stored copy is
//! rounded when the graph keeps halves.

mod build;
mod io;

use super::{kernels, Hit, Metric, VectorDtype};
use std::borrow::Cow;
use std::cell::RefCell;
use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;
use std::sync::RwLock;

const NONE: u32 = u32::MAX;

#[derive(Clone, Copy, PartialEq, PartialOrd)]
struct D(f32);
impl Eq for D {}
impl Ord for D {
    fn cmp(&self, o: &Self) -> Ordering {
        self.0.total_cmp(&o.0)
    }
}

/// The stored vectors, `n × dim`.
enum Vecs {
    F32(Vec<f32>),
    /// IEEE half-float bits.
    F16(Vec<u16>),
    /// Half floats for the walk, and the f32 vectors to re-score with.
    F16Refine(Vec<u16>, Vec<f32>),
}

impl Vecs {
    fn new(dtype: VectorDtype) -> Vecs {
        match dtype {
            VectorDtype::F32 => Vecs::F32(Vec::new()),
            VectorDtype::F16 => Vecs::F16(Vec::new()),
            VectorDtype::F16Refine => Vecs::F16Refine(Vec::new(), Vec::new()),
        }
    }
    fn push(&mut self, v: &[f32]) {
        match self {
            Vecs::F32(x) => x.extend_from_slice(v),
            Vecs::F16(x) => x.extend(kernels::half_float::encode(v)),
            Vecs::F16Refine(x, full) => {
                x.extend(kernels::half_float::encode(v));
                full.extend_from_slice(v);
            }
        }
    }
}

struct Graph {
    ids: Vec<u64>,
    vecs: Vecs,
    levels: Vec<u8>,
    links0: Vec<u32>,
    /// Per node, levels 1..=level, `m` links each (empty for level 0).
    upper: Vec<Vec<u32>>,
    entry: u32,
    max_level: usize,
}

pub struct FlatGraph {
    metric: Metric,
    dtype: VectorDtype,
    dim: usize,
    m: usize,
    m0: usize,
    ef_construction: usize,
    level_mult: f64,
    g: RwLock<Graph>,
    rng: std::sync::Mutex<u64>,
}

thread_local! {
    static VISITED: RefCell<(Vec<u32>, u32)> = const { RefCell::new((Vec::new(), 0)) };
}

/// Ask for the first cache lines of a vector (the hardware prefetcher
/// streams the rest once they arrive).
#[inline]
fn prefetch<T>(v: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = v.as_ptr() as *const i8;
        let lines = std::mem::size_of_val(v).div_ceil(64).min(4);
        for i in 0..lines {
            // SAFETY: prefetch never faults; the address is inside `v`.
            unsafe { _mm_prefetch(p.add(i * 64), _MM_HINT_T0) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

impl FlatGraph {
    pub fn new(
        metric: Metric,
        dtype: VectorDtype,
        dim: usize,
        m: usize,
        ef_construction: usize,
    ) -> FlatGraph {
        let m = m.max(2);
        FlatGraph {
            metric,
            dtype,
            dim,
            m,
            m0: 2 * m,
            ef_construction: ef_construction.max(m),
            level_mult: 1.0 / (m as f64).ln(),
            g: RwLock::new(Graph {
                ids: Vec::new(),
                vecs: Vecs::new(dtype),
                levels: Vec::new(),
                links0: Vec::new(),
                upper: Vec::new(),
                entry: NONE,
                max_level: 0,
            }),
            rng: std::sync::Mutex::new(0x2545_F491_4F6C_DD1D),
        }
    }

    pub fn len(&self) -> usize {
        self.g.read().expect("graph lock").ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The graph's distance from an f32 vector to stored node `n`.
    #[inline]
    fn dist(&self, g: &Graph, q: &[f32], n: u32) -> f32 {
        let (i, d) = (n as usize, self.dim);
        match (&g.vecs, self.metric) {
            (Vecs::F32(v), Metric::Cosine) => 1.0 - kernels::dot(q, &v[i * d..(i + 1) * d]),
            (Vecs::F32(v), Metric::Euclidean) => kernels::l2sq(q, &v[i * d..(i + 1) * d]),
            (Vecs::F16(v) | Vecs::F16Refine(v, _), Metric::Cosine) => {
                1.0 - kernels::dot_f16(q, &v[i * d..(i + 1) * d])
            }
            (Vecs::F16(v) | Vecs::F16Refine(v, _), Metric::Euclidean) => {
                kernels::l2sq_f16(q, &v[i * d..(i + 1) * d])
            }
        }
    }

    /// [`Self::dist`] to each of `nodes`, into `out`: f32 vectors are
    /// scored together ([`kernels::batch`]: one pass over the query for
    /// four of them).
    fn dists(&self, g: &Graph, q: &[f32], nodes: &[u32], out: &mut Vec<f32>) {
        match &g.vecs {
            Vecs::F32(v) => self.dists_f32(v, q, nodes, out),
            _ => {
                out.clear();
                out.extend(nodes.iter().map(|&n| self.dist(g, q, n)));
            }
        }
    }

    /// The metric's distance from `q` to each of `nodes` in the f32 rows
    /// `v` (the graph's own, or `f16-refine`'s kept copies).
    fn dists_f32(&self, v: &[f32], q: &[f32], nodes: &[u32], out: &mut Vec<f32>) {
        let d = self.dim;
        let rows: Vec<&[f32]> = nodes
            .iter()
            .map(|&n| &v[n as usize * d..(n as usize + 1) * d])
            .collect();
        let l2 = self.metric == Metric::Euclidean;
        kernels::batch(q, &rows, l2, out);
        if !l2 {
            out.iter_mut().for_each(|x| *x = 1.0 - *x);
        }
    }

    /// Node `n`'s vector as f32 (borrowed, or widened from halves).
    fn vec<'a>(&self, g: &'a Graph, n: u32) -> Cow<'a, [f32]> {
        let (i, d) = (n as usize, self.dim);
        match &g.vecs {
            Vecs::F32(v) | Vecs::F16Refine(_, v) => Cow::Borrowed(&v[i * d..(i + 1) * d]),
            Vecs::F16(v) => {
                let mut out = Vec::with_capacity(d);
                kernels::half_float::decode(&v[i * d..(i + 1) * d], &mut out);
                Cow::Owned(out)
            }
        }
    }

    /// Start loading node `n`'s vector into cache.
    #[inline]
    fn prefetch_node(&self, g: &Graph, n: u32) {
        let (i, d) = (n as usize, self.dim);
        match &g.vecs {
            Vecs::F32(v) => prefetch(&v[i * d..(i + 1) * d]),
            Vecs::F16(v) | Vecs::F16Refine(v, _) => prefetch(&v[i * d..(i + 1) * d]),
        }
    }

    /// The distance as the index reports it.
    fn reported(&self, d: f32) -> f32 {
        match self.metric {
            Metric::Cosine => d.max(0.0),
            Metric::Euclidean => d.max(0.0).sqrt(),
        }
    }

    fn random_level(&self) -> usize {
        let mut s = self.rng.lock().expect("rng");
        // xorshift64*
        *s ^= *s >> 12;
        *s ^= *s << 25;
        *s ^= *s >> 27;
        let r = s.wrapping_mul(0x2545_F491_4F6C_DD1D);
        let u = ((r >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        ((-u.ln() * self.level_mult) as usize).min(30)
    }

    fn links<'a>(&self, g: &'a Graph, i: u32, level: usize) -> &'a [u32] {
        let i = i as usize;
        if level == 0 {
            &g.links0[i * self.m0..(i + 1) * self.m0]
        } else {
            &g.upper[i][(level - 1) * self.m..level * self.m]
        }
    }

    fn links_mut<'a>(&self, g: &'a mut Graph, i: u32, level: usize) -> &'a mut [u32] {
        let i = i as usize;
        if level == 0 {
            &mut g.links0[i * self.m0..(i + 1) * self.m0]
        } else {
            &mut g.upper[i][(level - 1) * self.m..level * self.m]
        }
    }

    /// Greedy walk to the closest node on one upper layer.
    fn greedy(&self, g: &Graph, q: &[f32], mut ep: u32, mut d: f32, level: usize) -> (u32, f32) {
        let mut dists = Vec::with_capacity(self.m);
        loop {
            let links = self.links(g, ep, level);
            let links = &links[..links.iter().position(|&n| n == NONE).unwrap_or(links.len())];
            self.dists(g, q, links, &mut dists);
            let mut moved = false;
            for (&n, &dn) in links.iter().zip(&dists) {
                if dn < d {
                    (ep, d, moved) = (n, dn, true);
                }
            }
            if !moved {
                return (ep, d);
            }
        }
    }

    /// Beam search on one layer: up to `ef` closest (distance, node),
    /// ascending; only nodes passing `keep` enter the results, all guide
    /// the walk.
    fn layer_search(
        &self,
        g: &Graph,
        q: &[f32],
        ep: u32,
        ef: usize,
        level: usize,
        keep: &dyn Fn(u32) -> bool,
    ) -> Vec<(f32, u32)> {
        VISITED.with(|v| {
            let (marks, stamp) = &mut *v.borrow_mut();
            if marks.len() < g.ids.len() {
                marks.resize(g.ids.len(), 0);
            }
            *stamp = stamp.wrapping_add(1);
            if *stamp == 0 {
                marks.iter_mut().for_each(|m| *m = 0);
                *stamp = 1;
            }
            let stamp = *stamp;
            let mut cand: BinaryHeap<Reverse<(D, u32)>> = BinaryHeap::with_capacity(ef * 2);
            let mut best: BinaryHeap<(D, u32)> = BinaryHeap::with_capacity(ef + 1);
            let d0 = self.dist(g, q, ep);
            marks[ep as usize] = stamp;
            cand.push(Reverse((D(d0), ep)));
            if keep(ep) {
                best.push((D(d0), ep));
            }
            let mut fresh: Vec<u32> = Vec::with_capacity(self.m0);
            let mut dists: Vec<f32> = Vec::with_capacity(self.m0);
            while let Some(Reverse((D(dc), c))) = cand.pop() {
                if best.len() >= ef && dc > best.peek().map_or(f32::INFINITY, |b| b.0 .0) {
                    break;
                }
                // The unvisited neighbours first, their vectors prefetched,
                // then the distances: the loads overlap instead of each
                // distance waiting for memory.
                fresh.clear();
                for &n in self.links(g, c, level) {
                    if n == NONE {
                        break;
                    }
                    if marks[n as usize] != stamp {
                        marks[n as usize] = stamp;
                        fresh.push(n);
                        self.prefetch_node(g, n);
                    }
                }
                self.dists(g, q, &fresh, &mut dists);
                for (&n, &dn) in fresh.iter().zip(&dists) {
                    let worst = best.peek().map_or(f32::INFINITY, |b| b.0 .0);
                    if best.len() < ef || dn < worst {
                        cand.push(Reverse((D(dn), n)));
                        if keep(n) {
                            best.push((D(dn), n));
                            if best.len() > ef {
                                best.pop();
                            }
                        }
                    }
                }
            }
            let mut out: Vec<(f32, u32)> = best.into_iter().map(|(D(d), n)| (d, n)).collect();
            out.sort_by(|a, b| a.0.total_cmp(&b.0));
            out
        })
    }

    /// The neighbour-selection heuristic: closest first, skipping a
    /// candidate closer to an already chosen neighbour than to the point
    /// (keeps links spread over directions); topped up with the skipped
    /// closest when fewer than `m` survive.
    fn select(&self, g: &Graph, cands: &[(f32, u32)], m: usize) -> Vec<u32> {
        let mut chosen: Vec<(f32, u32)> = Vec::with_capacity(m);
        let mut skipped = Vec::new();
        for &(d, c) in cands {
            if chosen.len() >= m {
                break;
            }
            let vc = self.vec(g, c);
            if chosen.iter().all(|&(_, r)| self.dist(g, &vc, r) > d) {
                chosen.push((d, c));
            } else {
                skipped.push(c);
            }
        }
        let mut out: Vec<u32> = chosen.into_iter().map(|(_, c)| c).collect();
        for c in skipped {
            if out.len() >= m {
                break;
            }
            out.push(c);
        }
        out
    }

    /// Insert one raw (already prepared) vector: a batch of one
    /// ([`build`]), so single and bulk inserts share one mechanism.
    pub fn insert(&self, id: usize, v: &[f32]) {
        self.insert_batch(&[(id, v)]);
    }

    /// Node `n`'s links on a level re-chosen from `cands` by the heuristic.
    fn shrink(&self, g: &Graph, n: u32, cands: impl Iterator<Item = u32>, cap: usize) -> Vec<u32> {
        let vn = self.vec(g, n);
        let mut c: Vec<(f32, u32)> = cands.map(|c| (self.dist(g, &vn, c), c)).collect();
        c.sort_by(|a, b| a.0.total_cmp(&b.0));
        self.select(g, &c, cap)
    }

    /// The `k` nearest (external id, reported distance) to a prepared query
    /// among ids passing `filter`, closest first.
    pub fn search(
        &self,
        q: &[f32],
        k: usize,
        ef: usize,
        filter: Option<&(dyn Fn(usize) -> bool + Sync)>,
    ) -> Vec<Hit> {
        let g = self.g.read().expect("graph lock");
        if g.entry == NONE || k == 0 {
            return Vec::new();
        }
        let (mut ep, mut d) = (g.entry, self.dist(&g, q, g.entry));
        for l in (1..=g.max_level).rev() {
            (ep, d) = self.greedy(&g, q, ep, d, l);
        }
        let ids = &g.ids;
        let keep = |i: u32| filter.is_none_or(|f| f(ids[i as usize] as usize));
        let mut found = self.layer_search(&g, q, ep, ef.max(k), 0, &keep);
        if let Vecs::F16Refine(_, full) = &g.vecs {
            // Half floats moved each distance by about 1e-4: the best 2k
            // are re-scored with the f32 vectors and re-ordered, so hits
            // and their scores are exact (a point ranked past 2k by the
            // halves is not closer than the k-th in f32).
            found.truncate(2 * k);
            let nodes: Vec<u32> = found.iter().map(|&(_, n)| n).collect();
            let mut exact = Vec::with_capacity(nodes.len());
            self.dists_f32(full, q, &nodes, &mut exact);
            for ((dist, _), e) in found.iter_mut().zip(exact) {
                *dist = e;
            }
            found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        }
        found
            .into_iter()
            .take(k)
            .map(|(d, i)| Hit {
                id: ids[i as usize] as usize,
                distance: self.reported(d),
            })
            .collect()
    }
}
