//! Archive search end to end on fixtures built here: ingest (idempotent, bad
//! files reported), query (self-match, filters, HNSW = exact), index
//! staleness and corruption, bad queries.

use choreo::features::Embedding;
use choreo::index::hnsw::HnswParams;
use choreo::index::Metric;
use choreo::motion::io::amass::write_amass_npz;
use choreo::motion::{Labels, Motion, Skeleton};
use choreo::search::ingest::{ingest, IngestOptions};
use choreo::search::{QueryRequest, Searcher};
use choreo::store::Store;
use std::path::Path;

/// An SMPL clip whose arms and legs swing at `freq` Hz with a phase.
fn clip(name: &str, frames: usize, freq: f64, phase: f64, style: &str) -> Motion {
    let mut rots = vec![[0.0; 3]; frames * 24];
    let mut trans = Vec::new();
    for f in 0..frames {
        let t = f as f64 / 60.0;
        let s = (2.0 * std::f64::consts::PI * freq * t + phase).sin();
        rots[f * 24 + 1] = [0.6 * s, 0.0, 0.1];
        rots[f * 24 + 2] = [-0.6 * s, 0.0, -0.1];
        rots[f * 24 + 16] = [0.0, 0.0, -1.0 + 0.5 * s];
        rots[f * 24 + 17] = [0.0, 0.0, 1.0 - 0.5 * s];
        rots[f * 24 + 4] = [0.4 * (1.0 + s), 0.0, 0.0];
        trans.push([0.0, 0.9, 0.3 * t]);
    }
    let labels: Labels = [("style".to_string(), style.to_string())]
        .into_iter()
        .collect();
    Motion::new(name, 60.0, Skeleton::smpl24(), trans, rots, labels).unwrap()
}

fn write(dir: &Path, m: &Motion) {
    std::fs::write(
        dir.join(format!("{}.npz", m.name)),
        write_amass_npz(m).unwrap(),
    )
    .unwrap();
}

fn req(m: &Motion, start_s: f64, e: Embedding, metric: Metric) -> QueryRequest {
    QueryRequest {
        source: m.clone().into(),
        start_s,
        frames: 128,
        k: 5,
        embedding: e,
        metric,
        filters: vec![],
        exact: false,
        collections: None,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ingest_query_filters_staleness_and_errors() {
    let dir = tempfile::tempdir().unwrap();
    let files = dir.path().join("files");
    std::fs::create_dir(&files).unwrap();
    // Bandai-style names carry the labels (content, style).
    let slow = clip("dataset-1_swing_calm_001", 600, 0.5, 0.0, "calm");
    let fast = clip("dataset-1_swing_wild_001", 600, 3.0, 0.3, "wild");
    let mid = clip("dataset-1_sway_calm_002", 400, 1.5, 1.0, "calm");
    for m in [&slow, &fast, &mid] {
        write(&files, m);
    }
    std::fs::write(files.join("broken.bvh"), "HIERARCHY\nROOT x {").unwrap();
    std::fs::write(
        files.join("short.npz"),
        write_amass_npz(&clip("short", 60, 1.0, 0.0, "calm")).unwrap(),
    )
    .unwrap();
    let db = dir.path().join("t.db");
    let store = Store::open(&db).await.unwrap();
    let noop = |_: usize, _: usize, _: &str| {};
    let r = ingest(&store, &[files.clone()], &IngestOptions::default(), &noop)
        .await
        .unwrap();
    assert_eq!(r.files, 5);
    assert_eq!(r.motions, 4, "{r:?}");
    assert_eq!(r.errors.len(), 1);
    assert!(r.errors[0].file.ends_with("broken.bvh") && r.errors[0].reason.contains("broken.bvh"));
    // (600-128)/32+1 = 15 windows twice, (400-128)/32+1 = 9, short clip none.
    assert_eq!(r.windows, 15 + 15 + 9);
    // Idempotent.
    let again = ingest(&store, &[files.clone()], &IngestOptions::default(), &noop)
        .await
        .unwrap();
    assert_eq!((again.motions, again.skipped), (0, 4));

    let s = Searcher::open(store.clone(), HnswParams::default())
        .await
        .map(std::sync::Arc::new)
        .unwrap();
    for e in Embedding::ALL {
        for metric in Metric::ALL {
            // A window of `fast` finds itself first.
            let hits = s.query(req(&fast, 64.0 / 60.0, e, metric)).await.unwrap();
            assert!(
                hits[0].source_path.ends_with("swing_wild_001.npz"),
                "{e:?} {metric:?}: {hits:?}"
            );
            assert_eq!(hits[0].start_frame, 64);
            if metric == Metric::Cosine {
                assert!((hits[0].score - 1.0).abs() < 1e-4, "{}", hits[0].score);
            } else {
                assert!(hits[0].score.abs() < 1e-2, "{}", hits[0].score);
            }
            // HNSW equals exact on this small store.
            let mut ex = req(&fast, 64.0 / 60.0, e, metric);
            ex.exact = true;
            let exact = s.query(ex.clone()).await.unwrap();
            // (Periodic fixtures tie, so compare the ranked scores.)
            assert_eq!(hits.len(), exact.len());
            for (a, b) in hits.iter().zip(&exact) {
                assert!(
                    (a.score - b.score).abs() < 1e-4,
                    "{e:?} {metric:?}: {hits:?} vs {exact:?}"
                );
            }
        }
    }
    // Filters: only calm motions.
    let mut f = req(&fast, 0.0, Embedding::Dct, Metric::Cosine);
    f.filters = vec![("style".into(), "calm".into())];
    let hits = s.query(f.clone()).await.unwrap();
    assert_eq!(hits.len(), 5);
    assert!(hits.iter().all(|h| h.labels["style"] == "calm"));
    // A longer segment queries several windows.
    let mut long = req(&slow, 1.0, Embedding::Stft, Metric::Cosine);
    long.frames = 300;
    assert!(s.query(long.clone()).await.unwrap()[0]
        .source_path
        .ends_with("swing_calm_001.npz"));

    // Bad queries name the field.
    let short = clip("q", 100, 1.0, 0.0, "calm");
    let e = s
        .query(req(&short, 0.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("frames") && e.contains("past"), "{e}");
    let mut nan = fast.clone();
    nan.rotations[10][0] = f64::NAN;
    let e = s
        .query(req(&nan, 0.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("rotations") && e.contains("NaN"), "{e}");
    let alien = Motion::new(
        "alien",
        60.0,
        Skeleton::new(
            "custom",
            vec!["Root".into()],
            vec![None],
            vec![[0.0; 3]],
            vec![],
        )
        .unwrap(),
        vec![[0.0; 3]; 200],
        vec![[0.0; 3]; 200],
        Labels::new(),
    )
    .unwrap();
    let e = s
        .query(req(&alien, 0.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("joint map") || e.contains("Left_Hip"), "{e}");
    let mut k0 = req(&fast, 0.0, Embedding::Dct, Metric::Cosine);
    k0.k = 0;
    assert!(s
        .query(k0.clone())
        .await
        .unwrap_err()
        .to_string()
        .contains("k"));

    // The index was saved; after another ingest it is stale and rebuilt with
    // the new windows; a corrupt dump is rebuilt too.
    let base = format!("{}.dct-cosine", db.display());
    assert!(Path::new(&format!("{base}.meta.json")).exists());
    let extra = dir.path().join("extra");
    std::fs::create_dir(&extra).unwrap();
    let newer = clip("newer", 300, 2.2, 2.0, "wild");
    write(&extra, &newer);
    let tagged = IngestOptions {
        extra_labels: [("session".to_string(), "late".to_string())]
            .into_iter()
            .collect(),
        ..Default::default()
    };
    ingest(&store, &[extra], &tagged, &noop).await.unwrap();
    let s2 = Searcher::open(store.clone(), HnswParams::default())
        .await
        .map(std::sync::Arc::new)
        .unwrap();
    let hits = s2
        .query(req(&newer, 32.0 / 60.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap();
    assert!(hits[0].source_path.ends_with("newer.npz"), "{hits:?}");
    // Labels given at ingest filter too.
    let mut late = req(&fast, 0.0, Embedding::Dct, Metric::Cosine);
    late.filters = vec![("session".into(), "late".into())];
    let hits = s2.query(late.clone()).await.unwrap();
    assert!(!hits.is_empty() && hits.iter().all(|h| h.source_path.ends_with("newer.npz")));
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(format!("{base}.meta.json")).unwrap()).unwrap();
    // The dump the meta names (the flat graph's one file, or hnsw_rs's).
    let name = meta["dump_basename"].as_str().unwrap();
    let dump = ["flat", "hnsw.graph"]
        .iter()
        .map(|ext| dir.path().join(format!("{name}.{ext}")))
        .find(|p| p.exists())
        .unwrap_or_else(|| panic!("no dump for {name}"));
    std::fs::write(dump, b"garbage").unwrap();
    let s3 = Searcher::open(store.clone(), HnswParams::default())
        .await
        .map(std::sync::Arc::new)
        .unwrap();
    let hits = s3
        .query(req(&newer, 32.0 / 60.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap();
    assert!(hits[0].source_path.ends_with("newer.npz"));
    // Half floats (`--vector-dtype f16`): the f32 dump is another vector
    // type, so the index is rebuilt (its meta says f16) and answers as the
    // f32 one did, scores to about 1e-3.
    let half = HnswParams {
        dtype: choreo::index::VectorDtype::F16,
        ..HnswParams::default()
    };
    let s4 = Searcher::open(store.clone(), half)
        .await
        .map(std::sync::Arc::new)
        .unwrap();
    let h16 = s4
        .query(req(&newer, 32.0 / 60.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap();
    assert_eq!(h16.len(), hits.len());
    assert_eq!(
        (&h16[0].source_path, h16[0].start_frame),
        (&hits[0].source_path, hits[0].start_frame)
    );
    // Rank by rank the scores agree (near-ties may swap places).
    for (a, b) in h16.iter().zip(&hits) {
        assert!(
            (a.score - b.score).abs() < 1e-3,
            "{} vs {}",
            a.score,
            b.score
        );
    }
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(format!("{base}.meta.json")).unwrap()).unwrap();
    assert_eq!(meta["params"]["dtype"], "f16");
}

/// The live searcher: an ingest is found by the very next query (in every
/// built index, PCA included, on the basis in service), a delete vanishes
/// at once, labels sent with stored content are merged, a query by stored
/// id equals the query by the same clip, queries keep answering while
/// writes go on, and maintenance saves dumps a new searcher loads as they
/// are (no rebuild).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_writes_reach_queries_at_once() {
    use choreo::search::ingest::Stored;
    use choreo::search::QuerySource;
    use std::sync::Arc;
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("live.db");
    let store = Store::open(&db).await.unwrap();
    let files = dir.path().join("seed");
    std::fs::create_dir(&files).unwrap();
    for (i, f) in [0.5, 1.0, 1.5, 2.0].iter().enumerate() {
        write(&files, &clip(&format!("seed{i}"), 400, *f, 0.0, "calm"));
    }
    let noop = |_: usize, _: usize, _: &str| {};
    ingest(&store, &[files], &IngestOptions::default(), &noop)
        .await
        .unwrap();
    let s = Arc::new(
        Searcher::open(store.clone(), HnswParams::default())
            .await
            .unwrap(),
    );
    // Build every index before the writes.
    for e in Embedding::ALL {
        s.query(req(
            &clip("q", 200, 1.0, 0.0, "calm"),
            0.0,
            e,
            Metric::Cosine,
        ))
        .await
        .unwrap();
    }
    let opts = IngestOptions {
        keep_files: true,
        ..Default::default()
    };
    let novel = clip("novel", 500, 3.3, 0.7, "wild");
    let bytes = write_amass_npz(&novel).unwrap();
    let out = s
        .ingest("novel.npz", bytes.clone(), &opts)
        .await
        .unwrap()
        .unwrap();
    let Stored::New { motion_id, windows } = out.stored else {
        panic!("{out:?}")
    };
    assert_eq!(windows, (500 - 128) / 32 + 1);
    for e in Embedding::ALL {
        let hits = s
            .query(req(&novel, 64.0 / 60.0, e, Metric::Cosine))
            .await
            .unwrap();
        assert_eq!(hits[0].motion_id, motion_id, "{e:?}: {hits:?}");
        assert_eq!(hits[0].start_frame, 64, "{e:?}");
        assert!(hits[0].score > 0.9999, "{e:?}: {}", hits[0].score);
        // The same query by stored id.
        let mut by_id = req(&novel, 64.0 / 60.0, e, Metric::Cosine);
        by_id.source = QuerySource::Stored(motion_id);
        let again = s.query(by_id).await.unwrap();
        assert_eq!(again[0].motion_id, motion_id);
        assert!((again[0].score - hits[0].score).abs() < 1e-4, "{e:?}");
    }
    // An unknown stored id is not found.
    let mut gone = req(&novel, 0.0, Embedding::Dct, Metric::Cosine);
    gone.source = QuerySource::Stored(9999);
    assert!(matches!(
        s.query(gone).await,
        Err(choreo::search::QueryError::NotFound(9999))
    ));
    // The same bytes again with labels: nothing stored, labels merged.
    let tagged = IngestOptions {
        extra_labels: [("session".to_string(), "late".to_string())]
            .into_iter()
            .collect(),
        ..opts.clone()
    };
    let again = s
        .ingest("novel.npz", bytes, &tagged)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(again.stored, Stored::Existing { motion_id });
    let merged = again.merged_labels.unwrap();
    assert_eq!(merged["session"], "late");
    let mut late = req(&novel, 0.0, Embedding::Stft, Metric::Cosine);
    late.filters = vec![("session".into(), "late".into())];
    let hits = s.query(late).await.unwrap();
    assert!(!hits.is_empty() && hits.iter().all(|h| h.motion_id == motion_id));
    assert_eq!(hits[0].labels["session"], "late");

    // Queries keep answering while 6 takes are ingested one by one.
    let writer = {
        let s = s.clone();
        let opts = opts.clone();
        tokio::spawn(async move {
            for i in 0..6 {
                let m = clip(&format!("burst{i}"), 300, 0.7 + 0.4 * i as f64, 0.3, "calm");
                s.ingest(
                    &format!("burst{i}.npz"),
                    write_amass_npz(&m).unwrap(),
                    &opts,
                )
                .await
                .unwrap()
                .unwrap();
            }
        })
    };
    let mut slowest = std::time::Duration::ZERO;
    while !writer.is_finished() {
        let t = std::time::Instant::now();
        s.query(req(&novel, 0.5, Embedding::Stft, Metric::Cosine))
            .await
            .unwrap();
        slowest = slowest.max(t.elapsed());
    }
    writer.await.unwrap();
    assert!(
        slowest < std::time::Duration::from_secs(5),
        "a query took {slowest:?} during writes"
    );

    // Delete: gone from the next query of every index.
    assert!(s.delete(motion_id).await.unwrap());
    assert!(!s.delete(motion_id).await.unwrap());
    for e in Embedding::ALL {
        let hits = s
            .query(req(&novel, 64.0 / 60.0, e, Metric::Cosine))
            .await
            .unwrap();
        assert!(hits.iter().all(|h| h.motion_id != motion_id), "{e:?}");
    }
    // Maintenance: PCA refitted (the windows grew past the drift share),
    // dumps saved at the store's generation; a new searcher loads them and
    // answers the same.
    s.maintain().await.unwrap();
    assert!(!choreo::search::ingest::pca_due(&store).await.unwrap());
    let generation = store.generation().await.unwrap();
    let probe = clip("burst3", 300, 0.7 + 0.4 * 3.0, 0.3, "calm");
    let before = s
        .query(req(&probe, 0.5, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap();
    assert!(before[0].source_path.ends_with("burst3.npz"), "{before:?}");
    for e in Embedding::ALL {
        let meta: serde_json::Value = serde_json::from_slice(
            &std::fs::read(format!("{}.{}-cosine.meta.json", db.display(), e.name())).unwrap(),
        )
        .unwrap();
        assert_eq!(meta["generation"], generation, "{e:?}");
    }
    let s2 = Arc::new(
        Searcher::open(store.clone(), HnswParams::default())
            .await
            .unwrap(),
    );
    let after = s2
        .query(req(&probe, 0.5, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap();
    assert_eq!(
        before
            .iter()
            .map(|h| (h.motion_id, h.start_frame))
            .collect::<Vec<_>>(),
        after
            .iter()
            .map(|h| (h.motion_id, h.start_frame))
            .collect::<Vec<_>>()
    );
    // The loaded dump still holds the deleted windows' points, hidden.
    let ix = s2
        .index(Embedding::Dct, Metric::Cosine, false)
        .await
        .unwrap();
    assert_eq!(ix.len(), s2.window_count() + windows);
    let hits = s2
        .query(req(&novel, 64.0 / 60.0, Embedding::Dct, Metric::Cosine))
        .await
        .unwrap();
    assert!(hits.iter().all(|h| h.motion_id != motion_id));
}

/// The `lm` embedding (the bundled frame model's class heads' reading of a window): refused
/// clearly without a model; with one, the first `lm` query embeds every
/// stored window once (stored with the model's fingerprint), a window
/// finds itself, HNSW equals exact, a live ingest carries its `lm`
/// vectors, and a store embedded by another model is embedded again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lm_embedding_from_the_frame_model() {
    use choreo::lm::embed::LmEmbedder;
    use choreo::lm::model::MotionModel;
    use choreo::search::ingest::Stored;
    use std::sync::Arc;
    let model_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default");
    let model = MotionModel::load(&model_dir).unwrap();
    let emb = LmEmbedder::new(&model).unwrap();
    // The flat GPT has no per-frame state to pool.
    let flat =
        MotionModel::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("models/flat")).unwrap();
    let err = LmEmbedder::new(&flat).err().unwrap().to_string();
    assert!(err.contains("motion-frame-lm"), "{err}");

    let dir = tempfile::tempdir().unwrap();
    let files = dir.path().join("files");
    std::fs::create_dir(&files).unwrap();
    let fast = clip("fast", 400, 3.0, 0.3, "wild");
    for m in [
        &clip("slow", 400, 0.5, 0.0, "calm"),
        &fast,
        &clip("mid", 300, 1.5, 1.0, "calm"),
    ] {
        write(&files, m);
    }
    let store = Store::open(&dir.path().join("lm.db")).await.unwrap();
    let noop = |_: usize, _: usize, _: &str| {};
    let r = ingest(&store, &[files], &IngestOptions::default(), &noop)
        .await
        .unwrap();
    let s = Arc::new(
        Searcher::open(store.clone(), HnswParams::default())
            .await
            .unwrap(),
    );
    let q = req(&fast, 64.0 / 60.0, Embedding::Lm, Metric::Cosine);
    let err = s.query(q.clone()).await.err().unwrap().to_string();
    assert!(
        err.contains("embedding") && err.contains("frame model"),
        "{err}"
    );
    assert_eq!(store.count_embeddings(Embedding::Lm).await.unwrap(), 0);

    s.set_lm(emb.clone());
    let hits = s.query(q.clone()).await.unwrap();
    assert_eq!(
        store.count_embeddings(Embedding::Lm).await.unwrap(),
        r.windows
    );
    assert!(hits[0].source_path.ends_with("fast.npz"), "{hits:?}");
    assert_eq!(hits[0].start_frame, 64);
    assert!(hits[0].score > 0.9999, "{}", hits[0].score);
    let mut ex = q.clone();
    ex.exact = true;
    let exact = s.query(ex).await.unwrap();
    for (a, b) in hits.iter().zip(&exact) {
        assert!((a.score - b.score).abs() < 1e-5, "{hits:?} vs {exact:?}");
    }
    // Vectors are the model's width (mean and change of 192-d states).
    let v = store.embeddings(Embedding::Lm).await.unwrap();
    assert!(v
        .iter()
        .all(|(_, x)| x.len() == emb.dim() && x.iter().all(|f| f.is_finite())));

    // A live ingest carries its lm vectors into the built index.
    let novel = clip("novel", 300, 2.2, 0.7, "wild");
    let out = s
        .ingest(
            "novel.npz",
            write_amass_npz(&novel).unwrap(),
            &IngestOptions::default(),
        )
        .await
        .unwrap()
        .unwrap();
    let Stored::New { motion_id, windows } = out.stored else {
        panic!("{out:?}")
    };
    assert_eq!(
        store.count_embeddings(Embedding::Lm).await.unwrap(),
        r.windows + windows
    );
    let hits = s
        .query(req(&novel, 32.0 / 60.0, Embedding::Lm, Metric::Cosine))
        .await
        .unwrap();
    assert_eq!((hits[0].motion_id, hits[0].start_frame), (motion_id, 32));

    // Vectors made by another model are all made again.
    store
        .replace_embeddings(Embedding::Lm, &[], "lm", "lm-another-model", 0)
        .await
        .unwrap();
    let s2 = Arc::new(
        Searcher::open(store.clone(), HnswParams::default())
            .await
            .unwrap(),
    );
    s2.set_lm(emb);
    let hits = s2.query(q).await.unwrap();
    assert_eq!(
        store.count_embeddings(Embedding::Lm).await.unwrap(),
        r.windows + windows
    );
    assert!(hits[0].source_path.ends_with("fast.npz") && hits[0].score > 0.9999);
}

/// Processes opening one new SQLite store at the same moment (an ingest
/// and a server, or a test reading an ingest's file) all get the store:
/// SQLite has no migration lock, so the later ones' first CREATE meets the
/// first one's table, and the store runs its migrations again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stores_opened_at_once_on_a_new_file_all_open() {
    for round in 0..20 {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("race.db");
        let opens = (0..4).map(|_| {
            let db = db.clone();
            tokio::spawn(async move { Store::open(&db).await })
        });
        for o in futures_util::future::join_all(opens).await {
            let st = o.unwrap().unwrap_or_else(|e| panic!("round {round}: {e}"));
            assert_eq!(st.counts().await.unwrap().0, 0);
        }
    }
}
