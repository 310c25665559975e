//! Tests of `index/hnsw.rs`.

use super::super::ExactIndex;
use super::*;

fn latent(n: usize, dim: usize, seed: u64) -> Vec<Vec<f32>> {
    super::super::synthetic_latent(n, dim, seed)
}

/// HNSW agrees with exact search: recall@10 ≥ 0.98 on 3,000 vectors of
/// the DCT embedding's dimension, for both metrics, both graphs and the
/// flat graph's half-float storage (its bulk build runs the parallel
/// batches past the first 1,024 points), and again after a save/load
/// round trip.
#[test]
fn hnsw_recall_against_exact() {
    let dim = 1152;
    let data = latent(3000, dim, 1);
    let queries = latent(100, dim, 2);
    let dir = tempfile::tempdir().unwrap();
    for (metric, backend, dtype) in Metric::ALL.into_iter().flat_map(|m| {
        [
            (m, Backend::HnswRs, VectorDtype::F32),
            (m, Backend::Flat, VectorDtype::F32),
            (m, Backend::Flat, VectorDtype::F16),
            (m, Backend::Flat, VectorDtype::F16Refine),
        ]
    }) {
        let params = HnswParams {
            backend,
            dtype,
            ..Default::default()
        };
        let exact = ExactIndex::new(metric, dim);
        let items: Vec<(usize, Vec<f32>)> = data.iter().cloned().enumerate().collect();
        for (i, v) in &items {
            exact.add(*i, v);
        }
        // ef_search chosen for recall@10 >= 0.99 on held-out stored
        // vectors, measured against exact search, and kept in the meta.
        let h = HnswIndex::build_calibrated(metric, dim, params, &items, 100, 0.99);
        assert_eq!(h.len(), items.len());
        let (ef, r) = (h.params().ef_search, h.recall_at_10().unwrap());
        assert!(
            r >= 0.99 && ef <= 1024,
            "{} {backend:?}: ef {ef} recall {r}",
            metric.name()
        );
        let base = dir.path().join(format!(
            "ix-{}-{}-{}",
            metric.name(),
            backend.name(),
            dtype.name()
        ));
        h.save(&base, 7).unwrap();
        let loaded = HnswIndex::load(&base, metric, dtype, dim, data.len(), 7)
            .unwrap()
            .unwrap();
        assert_eq!(loaded.params().ef_search, ef);
        assert_eq!(loaded.params().dtype, dtype);
        assert_eq!(loaded.recall_at_10(), Some(r));
        assert!(
            HnswIndex::load(&base, metric, dtype, dim, data.len(), 8)
                .unwrap()
                .is_none(),
            "stale generation"
        );
        let other = match dtype {
            VectorDtype::F32 => VectorDtype::F16,
            VectorDtype::F16 => VectorDtype::F16Refine,
            VectorDtype::F16Refine => VectorDtype::F32,
        };
        assert!(
            HnswIndex::load(&base, metric, other, dim, data.len(), 7)
                .unwrap()
                .is_none(),
            "another vector type is stale: rebuilt"
        );
        for ix in [&h, &loaded] {
            let r: f64 = queries
                .iter()
                .map(|q| super::super::recall(&exact.search(q, 10, None), &ix.search(q, 10, None)))
                .sum::<f64>()
                / queries.len() as f64;
            assert!(
                r >= 0.98,
                "{} {backend:?} {dtype:?}: recall {r}",
                metric.name()
            );
        }
        // Distances are the metric's own (the exact index's).
        let (a, b) = (
            &h.search(&queries[1], 3, None),
            &exact.search(&queries[1], 3, None),
        );
        // (f16: the stored side is rounded, to a relative 2^-11.)
        // f16-refine re-scores with the f32 vectors: exact again.)
        let tol = match dtype {
            VectorDtype::F32 | VectorDtype::F16Refine => 1e-4,
            VectorDtype::F16 => 2e-3 * b[0].distance.max(1.0),
        };
        if a[0].id == b[0].id {
            assert!((a[0].distance - b[0].distance).abs() < tol, "{a:?} {b:?}");
        }
        if dtype != VectorDtype::F16 {
            // A stored vector finds itself at distance 0 (score 1 by cosine).
            for ix in [&h, &loaded] {
                let s = ix.search(&data[5], 1, None);
                assert!(
                    s[0].id == 5 && s[0].distance.abs() < 1e-5,
                    "{dtype:?} {s:?}"
                );
            }
        }
        // Filters hold, and still fill k.
        let even = |id: usize| id % 2 == 0;
        let f = h.search(&queries[0], 10, Some(&even));
        assert!(
            f.len() == 10 && f.iter().all(|x| x.id % 2 == 0),
            "{backend:?}"
        );
        // Live inserts are found at once.
        h.add_batch(&[(99_999, queries[3].clone())]);
        assert_eq!(h.search(&queries[3], 1, None)[0].id, 99_999);
    }
}

/// A truncated or scribbled flat dump is an error, never an index.
#[test]
fn corrupt_flat_dump_is_refused() {
    let dim = 16;
    let items: Vec<(usize, Vec<f32>)> = super::super::synthetic_latent(200, dim, 4)
        .into_iter()
        .enumerate()
        .collect();
    let params = HnswParams {
        backend: Backend::Flat,
        ..Default::default()
    };
    let h = HnswIndex::new(Metric::Cosine, dim, items.len(), params);
    h.add_batch(&items);
    let dir = tempfile::tempdir().unwrap();
    let base = dir.path().join("ix");
    let meta = h.save(&base, 1).unwrap();
    let file = dir.path().join(format!("{}.flat", meta.dump_basename));
    let good = std::fs::read(&file).unwrap();
    assert!(
        HnswIndex::load(&base, Metric::Cosine, VectorDtype::F32, dim, 200, 1)
            .unwrap()
            .is_some()
    );
    std::fs::write(&file, &good[..good.len() - 5]).unwrap();
    assert!(HnswIndex::load(&base, Metric::Cosine, VectorDtype::F32, dim, 200, 1).is_err());
    let mut bad = good.clone();
    let links_at = good.len() - 4 * 10;
    bad[links_at..links_at + 4].copy_from_slice(&5000u32.to_le_bytes());
    std::fs::write(&file, &bad).unwrap();
    assert!(HnswIndex::load(&base, Metric::Cosine, VectorDtype::F32, dim, 200, 1).is_err());
    assert!(
        HnswIndex::load(&base, Metric::Euclidean, VectorDtype::F32, dim, 200, 1)
            .unwrap()
            .is_none()
    );
}
