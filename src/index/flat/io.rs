//! The flat graph on disk: a magic, a header of little-endian words, then
//! the arrays. Version 2 adds the vector type (version 1 files, f32 only,
//! still load).

use super::{FlatGraph, Graph, Vecs, NONE};
use crate::index::{Metric, VectorDtype};
use std::io::{Read, Write};
use std::path::Path;

const MAGIC_V1: &[u8; 8] = b"CHFHNSW1";
const MAGIC: &[u8; 8] = b"CHFHNSW2";

impl FlatGraph {
    /// Write the graph to `path` (a temporary name, then renamed).
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let g = self.g.read().expect("graph lock");
        let tmp = path.with_extension("partial");
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        w.write_all(MAGIC)?;
        let head = [
            self.dim as u64,
            self.m as u64,
            self.ef_construction as u64,
            g.ids.len() as u64,
            g.entry as u64,
            g.max_level as u64,
            match self.metric {
                Metric::Cosine => 0,
                Metric::Euclidean => 1,
            },
            match self.dtype {
                VectorDtype::F32 => 0,
                VectorDtype::F16 => 1,
                VectorDtype::F16Refine => 2,
            },
        ];
        for h in head {
            w.write_all(&h.to_le_bytes())?;
        }
        for id in &g.ids {
            w.write_all(&id.to_le_bytes())?;
        }
        match &g.vecs {
            // The halves are made again from the f32 vectors on load.
            Vecs::F32(v) | Vecs::F16Refine(_, v) => {
                v.iter().try_for_each(|x| w.write_all(&x.to_le_bytes()))?
            }
            Vecs::F16(v) => v.iter().try_for_each(|x| w.write_all(&x.to_le_bytes()))?,
        }
        w.write_all(&g.levels)?;
        for x in &g.links0 {
            w.write_all(&x.to_le_bytes())?;
        }
        for u in &g.upper {
            for x in u {
                w.write_all(&x.to_le_bytes())?;
            }
        }
        w.flush()?;
        drop(w);
        std::fs::rename(tmp, path)
    }

    /// Read a graph [`FlatGraph::save`] wrote; every length and link is
    /// checked, so a truncated or corrupt file is an error, never a wrong
    /// answer. A graph of another metric, dimension or vector type is an
    /// error too (the caller rebuilds).
    pub fn load(
        path: &Path,
        metric: Metric,
        dtype: VectorDtype,
        dim: usize,
    ) -> anyhow::Result<FlatGraph> {
        let mut bytes = Vec::new();
        std::fs::File::open(path)?.read_to_end(&mut bytes)?;
        let bad = |what: &str| anyhow::anyhow!("{}: {what}", path.display());
        let words_in_head = match bytes.get(..8) {
            Some(m) if m == MAGIC => 8,
            Some(m) if m == MAGIC_V1 => 7,
            _ => return Err(bad("not a choreo flat HNSW file")),
        };
        let mut at = 8;
        // `n` little-endian words of `W` bytes from `at`, or "truncated".
        fn words<const W: usize, T>(
            bytes: &[u8],
            at: &mut usize,
            n: usize,
            from: fn([u8; W]) -> T,
        ) -> Option<Vec<T>> {
            let end = at.checked_add(n.checked_mul(W)?)?;
            let s = bytes.get(*at..end)?;
            *at = end;
            Some(
                s.chunks_exact(W)
                    .map(|c| from(c.try_into().expect("word")))
                    .collect(),
            )
        }
        let truncated = || bad("truncated");
        let h = words(&bytes, &mut at, words_in_head, u64::from_le_bytes).ok_or_else(truncated)?;
        let fdtype = match h.get(7).copied().unwrap_or(0) {
            0 => VectorDtype::F32,
            1 => VectorDtype::F16,
            2 => VectorDtype::F16Refine,
            _ => return Err(bad("unknown vector type")),
        };
        let (fdim, m, efc, n, entry, max_level, fmetric) = (
            h[0] as usize,
            h[1] as usize,
            h[2] as usize,
            h[3] as usize,
            h[4] as u32,
            h[5] as usize,
            h[6],
        );
        let want_metric = match metric {
            Metric::Cosine => 0,
            Metric::Euclidean => 1,
        };
        if fdim != dim || fmetric != want_metric || fdtype != dtype || m < 2 || max_level > 30 {
            return Err(bad(
                "built for another metric, dimension, vector type or shape",
            ));
        }
        let ids = words(&bytes, &mut at, n, u64::from_le_bytes).ok_or_else(truncated)?;
        let vecs = match dtype {
            VectorDtype::F32 => Vecs::F32(
                words(&bytes, &mut at, n * dim, f32::from_le_bytes).ok_or_else(truncated)?,
            ),
            VectorDtype::F16 => Vecs::F16(
                words(&bytes, &mut at, n * dim, u16::from_le_bytes).ok_or_else(truncated)?,
            ),
            VectorDtype::F16Refine => {
                let full =
                    words(&bytes, &mut at, n * dim, f32::from_le_bytes).ok_or_else(truncated)?;
                Vecs::F16Refine(crate::index::kernels::half_float::encode(&full), full)
            }
        };
        let finite = match &vecs {
            Vecs::F32(v) | Vecs::F16Refine(_, v) => v.iter().all(|x| x.is_finite()),
            Vecs::F16(v) => v.iter().all(|&x| ::half::f16::from_bits(x).is_finite()),
        };
        let levels = words(&bytes, &mut at, n, u8::from_le_bytes).ok_or_else(truncated)?;
        let links0 = words(&bytes, &mut at, n * 2 * m, u32::from_le_bytes).ok_or_else(truncated)?;
        let mut upper = Vec::with_capacity(n);
        for &l in &levels {
            upper.push(
                words(&bytes, &mut at, l as usize * m, u32::from_le_bytes).ok_or_else(truncated)?,
            );
        }
        if at != bytes.len() {
            return Err(bad("trailing bytes"));
        }
        let valid = |x: &u32| *x == NONE || (*x as usize) < n;
        if !links0.iter().all(valid)
            || !upper.iter().flatten().all(valid)
            || (n > 0 && (entry as usize >= n || levels[entry as usize] as usize != max_level))
            || !finite
        {
            return Err(bad("links, entry point or vectors out of range"));
        }
        let f = FlatGraph::new(metric, dtype, dim, m, efc);
        *f.g.write().expect("graph lock") = Graph {
            ids,
            vecs,
            levels,
            links0,
            upper,
            entry: if n == 0 { NONE } else { entry },
            max_level,
        };
        Ok(f)
    }
}
