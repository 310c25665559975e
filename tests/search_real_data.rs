//! Archive search on the real corpus (`CHOREO_DATA`): a killed ingest leaves
//! the store consistent and a re-run finishes the job; HNSW recall@10 against
//! exact search on every real window.

use choreo::data::require;
use choreo::features::Embedding;
use choreo::index::hnsw::{HnswIndex, HnswParams};
use choreo::index::{recall, AnnIndex, ExactIndex, Metric};
use choreo::store::Store;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

async fn consistent(store: &Store) -> (usize, usize) {
    let (motions, windows) = store.counts().await.unwrap();
    // Every window has its STFT and DCT embeddings; no orphans.
    assert_eq!(
        store.count_embeddings(Embedding::Stft).await.unwrap(),
        windows
    );
    assert_eq!(
        store.count_embeddings(Embedding::Dct).await.unwrap(),
        windows
    );
    let ch = store.all_channels().await.unwrap();
    assert_eq!(ch.len(), motions, "every motion has its channels");
    (motions, windows)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_ingest_loses_nothing_committed_and_rerun_completes() {
    let Some(bandai) = require("bandai") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("k.db");
    let mut child = Command::new(env!("CARGO_BIN_EXE_choreo"))
        .args(["ingest", "--db"])
        .arg(&db)
        .arg(&bandai)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill -9 once some motions are committed, well before the end.
    let t = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(100));
        if db.exists() {
            let st = Store::open(&db).await.unwrap();
            if st.counts().await.unwrap().0 >= 20 || t.elapsed() > Duration::from_secs(60) {
                break;
            }
        }
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let store = Store::open(&db).await.unwrap();
    let (before, _) = consistent(&store).await;
    assert!(
        before >= 20 && before < 524,
        "killed after {before} motions"
    );
    eprintln!("killed after {before} of 524 motions were committed");
    let out = Command::new(env!("CARGO_BIN_EXE_choreo"))
        .args(["ingest", "--json", "--db"])
        .arg(&db)
        .arg(&bandai)
        .output()
        .unwrap();
    assert!(out.status.success());
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["skipped"].as_u64().unwrap() as usize, before);
    assert_eq!(report["motions"].as_u64().unwrap() as usize, 524 - before);
    let (after, windows) = consistent(&store).await;
    assert_eq!(after, 524);
    assert_eq!(
        store.count_embeddings(Embedding::Pca).await.unwrap(),
        windows,
        "PCA refitted over all windows"
    );
}

/// Recall@10 of HNSW (default parameters) against exact search, every
/// embedding and metric, 300 queries drawn from the real windows of all of
/// `CHOREO_DATA` (AIST++ samples, Bandai, CMU).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hnsw_recall_on_the_real_corpus() {
    let Some(_) = require("bandai") else { return };
    let root = choreo::data::data_root();
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("r.db")).await.unwrap();
    let noop = |_: usize, _: usize, _: &str| {};
    choreo::search::ingest::ingest(&store, &[root], &Default::default(), &noop)
        .await
        .unwrap();
    for e in Embedding::ALL {
        let rows = store.embeddings(e).await.unwrap();
        let dim = rows[0].1.len();
        for metric in Metric::ALL {
            let exact = ExactIndex::new(metric, dim);
            let items: Vec<(usize, Vec<f32>)> = rows
                .iter()
                .map(|(id, v)| (*id as usize, v.clone()))
                .collect();
            for (id, v) in &items {
                exact.add(*id, v);
            }
            let h = HnswIndex::new(metric, dim, items.len(), HnswParams::default());
            h.add_batch(&items);
            let step = (items.len() / 300).max(1);
            let qs: Vec<&Vec<f32>> = items.iter().step_by(step).map(|(_, v)| v).collect();
            let r = qs
                .iter()
                .map(|q| recall(&exact.search(q, 10, None), &h.search(q, 10, None)))
                .sum::<f64>()
                / qs.len() as f64;
            eprintln!(
                "{} {}: {} windows, recall@10 {r:.4}",
                e.name(),
                metric.name(),
                items.len()
            );
            assert!(r >= 0.98, "{} {}: recall {r}", e.name(), metric.name());
        }
    }
}
