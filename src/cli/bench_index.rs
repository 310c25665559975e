//! `choreo bench index`: exact search and choreo's HNSW on synthetic
//! vectors (a 16-d latent lifted to `dim`), one JSON object of rows in the
//! shape `scripts/bench_faiss.py` prints too, so `scripts/bench_index.sh`
//! can set them side by side.

use super::{percentile, rss_mb, write_npy_f32};
use anyhow::Result;
use choreo::index::hnsw::{Backend, HnswIndex, HnswParams};
use choreo::index::{
    kernels, recall, synthetic_latent, AnnIndex, ExactIndex, Hit, Metric, VectorDtype,
};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

pub struct Bench {
    pub sizes: Vec<usize>,
    pub dim: usize,
    pub queries: usize,
    pub metric: Metric,
    /// Also write base_N.npy, queries.npy and gt_N.npy here.
    pub dump: Option<PathBuf>,
    pub params: HnswParams,
    /// With `dump`: vectors and ground truth only, no HNSW build.
    pub dump_only: bool,
    /// Also report the smallest ef_search reaching this recall (0 = off).
    pub target_recall: f64,
    /// The HNSW graphs to build and measure.
    pub backends: Vec<choreo::index::hnsw::Backend>,
    /// The vector types to measure each graph with (f16: flat graph only).
    pub dtypes: Vec<VectorDtype>,
    /// Also build each graph as the server does (ef_search calibrated on
    /// held-out stored vectors): a second build.
    pub server_build: bool,
    /// Print `{"rows": [...]}`; otherwise a markdown table.
    pub json: bool,
}

/// Latency percentiles, QPS (one thread) and mean recall of a search fn.
fn measure(
    queries: &[Vec<f32>],
    truth: &[Vec<Hit>],
    search: impl Fn(&[f32]) -> Vec<Hit>,
) -> (f64, f64, f64, f64) {
    let mut lat = Vec::with_capacity(queries.len());
    let mut rec = 0.0;
    for (q, t) in queries.iter().zip(truth) {
        let t0 = Instant::now();
        let r = search(q);
        lat.push(t0.elapsed().as_secs_f64() * 1e3);
        rec += recall(t, &r);
    }
    lat.sort_by(f64::total_cmp);
    let qps = 1e3 * lat.len() as f64 / lat.iter().sum::<f64>();
    (
        percentile(&lat, 0.5),
        percentile(&lat, 0.95),
        qps,
        rec / queries.len() as f64,
    )
}

fn row(
    n: usize,
    index: &str,
    dtype: VectorDtype,
    build_s: Option<f64>,
    m: (f64, f64, f64, f64),
    extra: Value,
) -> Value {
    let mut r = json!({
        "n": n, "index": index, "dtype": dtype.name(), "build_s": build_s,
        "p50_ms": m.0, "p95_ms": m.1, "qps": m.2, "recall_at_10": m.3,
        "rss_mb": rss_mb().0,
    });
    if let (Some(r), Some(e)) = (r.as_object_mut(), extra.as_object()) {
        r.extend(e.clone());
    }
    r
}

pub fn run(b: &Bench) -> Result<()> {
    let queries = synthetic_latent(b.queries, b.dim, 99);
    if let Some(d) = &b.dump {
        std::fs::create_dir_all(d)?;
        write_npy_f32(
            &d.join("queries.npy"),
            b.dim,
            queries.iter().map(|q| q.as_slice()),
        )?;
    }
    let mut rows = Vec::new();
    for &n in &b.sizes {
        let items: Vec<(usize, Vec<f32>)> = synthetic_latent(n, b.dim, 1)
            .into_iter()
            .enumerate()
            .collect();
        let exact = ExactIndex::new(b.metric, b.dim);
        for (i, v) in &items {
            exact.add(*i, v);
        }
        let truth: Vec<Vec<Hit>> = queries.iter().map(|q| exact.search(q, 10, None)).collect();
        rows.push(row(
            n,
            "exact",
            VectorDtype::F32,
            None,
            measure(&queries, &truth, |q| exact.search(q, 10, None)),
            json!({"kernel": kernels::active().name()}),
        ));
        drop(exact);
        if let Some(d) = &b.dump {
            write_npy_f32(
                &d.join(format!("base_{n}.npy")),
                b.dim,
                items.iter().map(|(_, v)| v.as_slice()),
            )?;
            let gt: Vec<Vec<f32>> = truth
                .iter()
                .map(|h| h.iter().map(|x| x.id as f32).collect())
                .collect();
            let k = gt.first().map_or(0, |g| g.len());
            write_npy_f32(
                &d.join(format!("gt_{n}.npy")),
                k,
                gt.iter().map(|g| g.as_slice()),
            )?;
        }
        if b.dump_only {
            continue;
        }
        for &backend in &b.backends {
            for &dtype in &b.dtypes {
                if dtype.is_half() && backend == Backend::HnswRs {
                    continue;
                }
                let p = HnswParams {
                    backend,
                    dtype,
                    ..b.params
                };
                rows.extend(hnsw_rows(b, n, p, &items, &queries, &truth));
            }
        }
    }
    if b.json {
        println!(
            "{}",
            json!({"rows": rows, "dim": b.dim, "metric": b.metric, "queries": b.queries})
        );
        return Ok(());
    }
    println!("| n | index | dtype | efSearch (chosen by) | build s | p50 ms | p95 ms | QPS (1 thread) | recall@10 | RSS MB |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let num = |v: &Value, p: usize| v.as_f64().map_or("–".into(), |x| format!("{x:.p$}"));
    for r in &rows {
        let ef = match (r.get("ef_search"), r.get("ef_chosen_by")) {
            (Some(e), Some(by)) => format!("{e} ({})", by.as_str().unwrap_or("")),
            _ => "–".into(),
        };
        println!(
            "| {} | {} | {} | {ef} | {} | {} | {} | {} | {} | {} |",
            r["n"],
            r["index"].as_str().unwrap_or(""),
            r["dtype"].as_str().unwrap_or(""),
            num(&r["build_s"], 1),
            num(&r["p50_ms"], 3),
            num(&r["p95_ms"], 3),
            num(&r["qps"], 0),
            num(&r["recall_at_10"], 4),
            num(&r["rss_mb"], 0),
        );
    }
    Ok(())
}

/// One graph's rows: at `--ef-search`, at the smallest ef reaching the
/// target recall on the queries, and as the server builds it (ef chosen on
/// held-out stored vectors).
fn hnsw_rows(
    b: &Bench,
    n: usize,
    p: HnswParams,
    items: &[(usize, Vec<f32>)],
    queries: &[Vec<f32>],
    truth: &[Vec<Hit>],
) -> Vec<Value> {
    let mut rows = Vec::new();
    let t = Instant::now();
    let mut h = HnswIndex::new(b.metric, b.dim, n, p);
    h.add_batch(items);
    let build_s = t.elapsed().as_secs_f64();
    let name = format!("choreo-hnsw ({})", p.backend.name());
    let common = json!({"m": p.m, "ef_construction": p.ef_construction,
                        "kernel": kernels::active().name()});
    let at = |h: &HnswIndex, note: &str| {
        let mut extra = common.clone();
        extra["ef_search"] = json!(h.params().ef_search);
        extra["ef_chosen_by"] = json!(note);
        row(
            n,
            &name,
            p.dtype,
            Some(build_s),
            measure(queries, truth, |q| h.search(q, 10, None)),
            extra,
        )
    };
    rows.push(at(&h, "--ef-search"));
    if b.target_recall <= 0.0 {
        return rows;
    }
    // The smallest ef on the ladder reaching the target on these queries:
    // how bench_faiss.py sets FAISS's efSearch too.
    for ef in [10, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512] {
        h.set_ef_search(ef);
        let r = measure(queries, truth, |q| h.search(q, 10, None)).3;
        if r >= b.target_recall || ef == 512 {
            rows.push(at(&h, &format!("recall>={}", b.target_recall)));
            break;
        }
    }
    drop(h);
    if !b.server_build {
        return rows;
    }
    let t = Instant::now();
    let h = HnswIndex::build_calibrated(b.metric, b.dim, p, items, 100, b.target_recall);
    let mut extra = common.clone();
    extra["ef_search"] = json!(h.params().ef_search);
    extra["ef_chosen_by"] = json!("server calibration (held-out stored vectors)");
    extra["calibration_recall"] = json!(h.recall_at_10());
    rows.push(row(
        n,
        &name,
        p.dtype,
        Some(t.elapsed().as_secs_f64()),
        measure(queries, truth, |q| h.search(q, 10, None)),
        extra,
    ));
    rows
}
