//! Bulk insertion on every core. Points go in batches: the batch's points
//! are appended (no links yet), then each one's neighbours are found in
//! parallel against the graph as it stood, plus the batch's earlier points
//! (so the batch sees itself as sequential inserts would); the new nodes'
//! links are written, and every old node that gains a link re-chooses its
//! list in parallel, one task per (node, level). The graph's write lock is
//! held throughout; a batch is at most 1/16 of the graph (and 128 points:
//! each point also measures the batch's earlier ones), and the first
//! points go in one by one, so a batch's points never lack a graph to
//! search.

use super::{FlatGraph, Graph, NONE};
use rayon::prelude::*;

/// Points inserted one by one before batches start.
const SERIAL_FIRST: usize = 1024;
const MIN_BATCH: usize = 32;
const MAX_BATCH: usize = 128;

impl FlatGraph {
    /// Insert many prepared vectors (external id, vector), on every core
    /// rayon has; one core, or few points, insert one by one.
    pub fn insert_many(&self, items: &[(usize, &[f32])]) {
        let parallel = rayon::current_num_threads() > 1;
        let mut i = 0;
        while i < items.len() {
            let len = self.len();
            let left = items.len() - i;
            if !parallel || len < SERIAL_FIRST || left < MIN_BATCH {
                self.insert(items[i].0, items[i].1);
                i += 1;
                continue;
            }
            let b = (len / 16).clamp(MIN_BATCH, MAX_BATCH).min(left);
            self.insert_batch(&items[i..i + b]);
            i += b;
        }
    }

    /// Insert `batch` (one point: a plain insert) under the write lock.
    pub(super) fn insert_batch(&self, batch: &[(usize, &[f32])]) {
        for (_, v) in batch {
            assert_eq!(v.len(), self.dim, "vector dimension");
        }
        let levels: Vec<usize> = batch.iter().map(|_| self.random_level()).collect();
        let mut g = self.g.write().expect("graph lock");
        let base = g.ids.len() as u32;
        for ((id, v), &level) in batch.iter().zip(&levels) {
            g.ids.push(*id as u64);
            g.vecs.push(v);
            g.levels.push(level as u8);
            g.links0.extend(std::iter::repeat_n(NONE, self.m0));
            g.upper.push(vec![NONE; level * self.m]);
        }
        // Each new point's chosen neighbours per level, found in parallel
        // (a single point on the calling thread).
        let plans: Vec<Vec<Vec<u32>>> = {
            let gr: &Graph = &g;
            let plan = |j: usize| self.plan(gr, batch[j].1, &levels, j, base);
            if batch.len() == 1 {
                vec![plan(0)]
            } else {
                (0..batch.len()).into_par_iter().map(plan).collect()
            }
        };
        let mut back: Vec<(u32, u8, u32)> = Vec::new();
        for (j, plan) in plans.iter().enumerate() {
            let me = base + j as u32;
            for (l, chosen) in plan.iter().enumerate() {
                let mine = self.links_mut(&mut g, me, l);
                for (slot, &n) in mine.iter_mut().zip(chosen) {
                    *slot = n;
                }
                back.extend(chosen.iter().map(|&n| (n, l as u8, me)));
            }
        }
        // The reverse links, one task per (node, level).
        back.sort_unstable();
        let groups: Vec<&[(u32, u8, u32)]> =
            back.chunk_by(|a, b| (a.0, a.1) == (b.0, b.1)).collect();
        let lists: Vec<(u32, usize, Vec<u32>)> = {
            let gr: &Graph = &g;
            let relink = |grp: &&[(u32, u8, u32)]| {
                let (n, l) = (grp[0].0, grp[0].1 as usize);
                let cap = if l == 0 { self.m0 } else { self.m };
                let cur = self
                    .links(gr, n, l)
                    .iter()
                    .copied()
                    .take_while(|&x| x != NONE);
                let new = grp.iter().map(|x| x.2);
                let all: Vec<u32> = cur.chain(new).collect();
                let list = if all.len() <= cap {
                    all
                } else {
                    self.shrink(gr, n, all.into_iter(), cap)
                };
                (n, l, list)
            };
            if batch.len() == 1 {
                groups.iter().map(relink).collect()
            } else {
                groups.par_iter().map(relink).collect()
            }
        };
        for (n, l, list) in lists {
            let slots = self.links_mut(&mut g, n, l);
            for (i, s) in slots.iter_mut().enumerate() {
                *s = list.get(i).copied().unwrap_or(NONE);
            }
        }
        for (j, &level) in levels.iter().enumerate() {
            if g.entry == NONE || level > g.max_level {
                g.max_level = level;
                g.entry = base + j as u32;
            }
        }
    }

    /// Point `j` of a batch (stored at `base + j`, no links yet): its
    /// chosen neighbours on each of its levels, from a search of the graph
    /// before the batch plus the batch's earlier points.
    fn plan(&self, g: &Graph, v: &[f32], levels: &[usize], j: usize, base: u32) -> Vec<Vec<u32>> {
        let level = levels[j];
        let all = |_: u32| true;
        let mates: Vec<(f32, u32, usize)> = (0..j)
            .map(|k| (self.dist(g, v, base + k as u32), base + k as u32, levels[k]))
            .collect();
        let top = g.max_level;
        let mut out = vec![Vec::new(); level + 1];
        let mut ep = (g.entry != NONE).then(|| {
            let (mut ep, mut d) = (g.entry, self.dist(g, v, g.entry));
            for l in (level + 1..=top).rev() {
                (ep, d) = self.greedy(g, v, ep, d, l);
            }
            ep
        });
        for l in (0..=level).rev() {
            let mut cands = match ep {
                Some(e) if l <= top => {
                    let c = self.layer_search(g, v, e, self.ef_construction, l, &all);
                    ep = c.first().map(|x| x.1).or(ep);
                    c
                }
                _ => Vec::new(),
            };
            cands.extend(mates.iter().filter(|m| m.2 >= l).map(|m| (m.0, m.1)));
            cands.sort_by(|a, b| a.0.total_cmp(&b.0));
            out[l] = self.select(g, &cands, self.m);
        }
        out
    }
}
