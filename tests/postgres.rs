//! PostgreSQL as the shared store (needs `CHOREO_TEST_POSTGRES`; see
//! tests/support/pg.rs): the store's API gives the same answers on SQLite
//! and PostgreSQL; three `choreo serve` replicas on one database see every
//! write made through any of them; the same file sent to two replicas at
//! once is stored once under one id; a replica killed mid-ingest loses
//! nothing it acknowledged; a database migrated by a newer choreo is
//! refused. The database restart test is in tests/postgres_outage.rs (its
//! own binary, so no other test's database goes away under it).

mod support;

use choreo::search::ingest::{ingest_bytes, IngestOptions, Stored};
use choreo::store::{Location, Store, StoreError};
use serde_json::json;
use std::time::{Duration, Instant};
use support::pg::{self, TOKEN};

/// One sequence of store operations on real files; what it saw, for
/// comparing the two engines.
async fn exercise(store: &Store, files: &[std::path::PathBuf]) -> serde_json::Value {
    let mut ids = Vec::new();
    for f in files {
        let bytes = std::fs::read(f).unwrap();
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        match ingest_bytes(store, &name, bytes, &IngestOptions::default())
            .await
            .unwrap()
            .unwrap()
        {
            Stored::New { motion_id, .. } => ids.push(motion_id),
            other => panic!("{name}: {other:?}"),
        }
    }
    // The same bytes again: the same motion.
    let again = ingest_bytes(
        store,
        "again.pkl",
        std::fs::read(&files[0]).unwrap(),
        &IngestOptions::default(),
    )
    .await
    .unwrap()
    .unwrap();
    assert_eq!(again, Stored::Existing { motion_id: ids[0] });
    // Ids are never reused: delete the newest, ingest another.
    assert!(store.delete_motion(*ids.last().unwrap()).await.unwrap());
    let bytes = std::fs::read(files.last().unwrap()).unwrap();
    let Stored::New {
        motion_id: reborn, ..
    } = ingest_bytes(store, "reborn.pkl", bytes, &IngestOptions::default())
        .await
        .unwrap()
        .unwrap()
    else {
        panic!("not stored again")
    };
    assert!(reborn > *ids.last().unwrap(), "id {reborn} reused");
    let mut labels = choreo::motion::Labels::new();
    labels.insert("style".into(), "studio".into());
    let merged = store.merge_labels(ids[0], &labels).await.unwrap().unwrap();
    let filtered = store
        .motions_with_labels(&[("style".into(), "studio".into())])
        .await
        .unwrap();
    let windows = store.windows().await.unwrap();
    let mut embeddings = Vec::new();
    for kind in [
        choreo::features::Embedding::Stft,
        choreo::features::Embedding::Dct,
        choreo::features::Embedding::Pose,
    ] {
        let e = store.embeddings(kind).await.unwrap();
        let first_motion = store.motion_embeddings(ids[0], kind).await.unwrap();
        embeddings.push(json!({
            "kind": kind.name(),
            "count": e.len(),
            "first": e.first().map(|(_, v)| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()),
            "first_motion": first_motion.len(),
        }));
    }
    // Adding vectors of a kind keeps any a window already has (the lm
    // backfill's write): the second add changes nothing.
    let lm = choreo::features::Embedding::Lm;
    let (w0, w1) = (windows[0].0, windows[1].0);
    store
        .add_embeddings(lm, &[(w0, vec![1.0, 2.0])])
        .await
        .unwrap();
    store
        .add_embeddings(lm, &[(w0, vec![9.0, 9.0]), (w1, vec![3.0, 4.0])])
        .await
        .unwrap();
    let mut added = store.embeddings(lm).await.unwrap();
    added.sort_by_key(|(id, _)| *id);
    assert_eq!(added, vec![(w0, vec![1.0, 2.0]), (w1, vec![3.0, 4.0])]);
    embeddings.push(json!({"kind": "lm", "added": added}));
    let range = store.channel_range(ids[0], 10, 3).await.unwrap().unwrap();
    store.create_collection("films").await.unwrap();
    store
        .audit_append("tester", "ingest", "motion 1", "req-1")
        .await
        .unwrap();
    let audit = store.audit(10).await.unwrap();
    json!({
        "ids": ids.len(),
        "reborn_after_last": reborn - ids.last().unwrap(),
        "merged": merged,
        "filtered": filtered.len(),
        "windows": windows.len(),
        "embeddings": embeddings,
        "range": [range.0, range.1.len(), range.1[0][0].to_bits()],
        "collections": store.collections().await.unwrap(),
        "audit": audit.iter().map(|a| (a.actor.clone(), a.action.clone())).collect::<Vec<_>>(),
        "counts": store.counts().await.unwrap(),
        "generation_moved": store.generation().await.unwrap() > 0,
    })
}

/// The store's operations answer the same on SQLite and PostgreSQL, and
/// both refuse to change the audit trail.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn store_answers_the_same_on_sqlite_and_postgres() {
    let Some(admin) = pg::admin_url() else {
        return;
    };
    let Some(dir) = choreo::data::require("aistpp-vrm/motions") else {
        return;
    };
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files.truncate(3);
    let tmp = tempfile::tempdir().unwrap();
    let lite = Store::open(&tmp.path().join("choreo.db")).await.unwrap();
    let url = pg::fresh_db(&admin, "contract").await;
    let pgs = Store::open_at(&Location::Postgres(url.clone()), Some(tmp.path()))
        .await
        .unwrap();
    let a = exercise(&lite, &files).await;
    let b = exercise(&pgs, &files).await;
    assert_eq!(a, b, "SQLite (left) and PostgreSQL (right) differ");
    println!(
        "both engines: {} motions, {} windows, ids never reused, labels merged, audit append-only",
        a["counts"][0], a["windows"]
    );
    for (what, err) in [
        (
            "sqlite",
            sqlx::query("UPDATE audit SET actor = 'x'")
                .execute(
                    &sqlx::SqlitePool::connect(&format!(
                        "sqlite://{}",
                        tmp.path().join("choreo.db").display()
                    ))
                    .await
                    .unwrap(),
                )
                .await
                .err(),
        ),
        (
            "postgres",
            sqlx::query("DELETE FROM audit")
                .execute(&sqlx::PgPool::connect(&url).await.unwrap())
                .await
                .err(),
        ),
    ] {
        let e = err.unwrap_or_else(|| panic!("{what}: the audit trail was changed"));
        assert!(e.to_string().contains("append-only"), "{what}: {e}");
    }
}

/// A store migrated by a newer choreo is refused, naming both versions; a
/// malformed or unreachable URL is a clear error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn newer_or_unreachable_stores_are_refused_clearly() {
    let Some(admin) = pg::admin_url() else {
        return;
    };
    let url = pg::fresh_db(&admin, "future").await;
    let tmp = tempfile::tempdir().unwrap();
    let loc = Location::Postgres(url.clone());
    drop(Store::open_at(&loc, Some(tmp.path())).await.unwrap());
    sqlx::query(
        "INSERT INTO _sqlx_migrations (version, description, success, checksum, execution_time)
         VALUES (9999, 'from the future', true, '\\x00', 0)",
    )
    .execute(&sqlx::PgPool::connect(&url).await.unwrap())
    .await
    .unwrap();
    let e = Store::open_at(&loc, Some(tmp.path())).await.err().unwrap();
    assert!(matches!(e, StoreError::TooNew { found: 9999, .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("9999") && msg.contains("newer choreo"),
        "{msg}"
    );

    let refused = Location::parse("postgres://choreo:hunter2@127.0.0.1:1/none").unwrap();
    let e = Store::open_at(&refused, Some(tmp.path()))
        .await
        .err()
        .unwrap();
    let msg = e.to_string();
    assert!(matches!(e, StoreError::Unavailable { .. }), "{msg}");
    assert!(msg.contains("refused") && !msg.contains("hunter2"), "{msg}");
    assert!(Location::parse("mysql://x/y")
        .unwrap_err()
        .contains("postgres://"));
}

/// Three replicas on one database: 50 dances ingested through A while B
/// and C answer queries; each is found through B and C (the replica's own
/// index) soon after A acknowledged it; queries never fail meanwhile; the
/// same file sent to two replicas at once is stored once, under one id.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_replicas_see_every_write() {
    let Some(admin) = pg::admin_url() else {
        return;
    };
    let Some(takes) = pg::vrm_takes(52) else {
        return;
    };
    let url = pg::fresh_db(&admin, "replicas").await;
    let dirs: Vec<_> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();
    let (a, ha) = pg::spawn_replica(&url, dirs[0].path());
    let (b, hb) = pg::spawn_replica(&url, dirs[1].path());
    let (c, hc) = pg::spawn_replica(&url, dirs[2].path());
    let report = tokio::task::spawn_blocking(move || {
        let post = |h, body: &serde_json::Value| {
            support::exchange(h, "POST", "/v1/motions", Some(body), Some(TOKEN)).unwrap()
        };
        // A first dance, seen by all, for the readers to query.
        let (s, _, v) = post(ha, &takes[0].1);
        assert_eq!(s, 201, "{v}");
        let first = v["motion_id"].as_i64().unwrap();
        let wait_found = |h, id| {
            let t0 = Instant::now();
            loop {
                if pg::top_hit(h, id) == (200, Some(id)) {
                    return t0.elapsed();
                }
                assert!(
                    t0.elapsed() < Duration::from_secs(20),
                    "motion {id} never found"
                );
                std::thread::sleep(Duration::from_millis(10));
            }
        };
        wait_found(hb, first);
        wait_found(hc, first);
        // Readers on B and C for the whole ingest.
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let readers: Vec<_> = [hb, hc]
            .into_iter()
            .map(|h| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut statuses = std::collections::BTreeMap::<u16, usize>::new();
                    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                        *statuses.entry(pg::top_hit(h, first).0).or_default() += 1;
                    }
                    statuses
                })
            })
            .collect();
        let mut lags = Vec::new();
        for (name, body) in &takes[1..51] {
            let (s, _, v) = post(ha, body);
            assert_eq!(s, 201, "{name}: {v}");
            let id = v["motion_id"].as_i64().unwrap();
            let acked = Instant::now();
            wait_found(hb, id);
            wait_found(hc, id);
            lags.push(acked.elapsed().as_secs_f64() * 1e3);
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let reads: Vec<_> = readers.into_iter().map(|r| r.join().unwrap()).collect();
        // The same file through B and C at the same moment.
        let body = takes[51].1.clone();
        let (b2, c2) = (body.clone(), body);
        let tb = std::thread::spawn(move || post(hb, &b2));
        let tc = std::thread::spawn(move || post(hc, &c2));
        let (rb, rc) = (tb.join().unwrap(), tc.join().unwrap());
        (lags, reads, rb, rc)
    })
    .await
    .unwrap();
    let (mut lags, reads, rb, rc) = report;
    for r in &reads {
        assert_eq!(
            r.keys().copied().collect::<Vec<_>>(),
            vec![200],
            "queries during ingest: {r:?}"
        );
    }
    lags.sort_by(f64::total_cmp);
    println!(
        "write through A → found through B and C: median {:.0} ms, max {:.0} ms over {} dances; reads {:?}",
        lags[lags.len() / 2],
        lags[lags.len() - 1],
        lags.len(),
        reads
    );
    assert!(lags[lags.len() - 1] < 5000.0, "{lags:?}");
    assert_eq!(
        rb.2["motion_id"], rc.2["motion_id"],
        "one file, two ids: {rb:?} {rc:?}"
    );
    let mut statuses = [rb.0, rc.0];
    statuses.sort();
    // Stored once: one "new" (201), one "existing" (200).
    assert_eq!(statuses, [200, 201], "{rb:?} {rc:?}");
    // Every replica lists the same 52 motions.
    for h in [ha, hb, hc] {
        let (s, _, v) = support::exchange(h, "GET", "/v1/motions", None, None).unwrap();
        assert_eq!(s, 200);
        assert_eq!(v["motions"].as_array().unwrap().len(), 52);
    }
    for child in [a, b, c] {
        pg::kill(child);
    }
}

/// kill -9 a replica mid-ingest: every motion it acknowledged is in the
/// shared store whole (its windows, and an embedding of every kind for
/// each), and nothing half-written is.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replica_killed_mid_ingest_loses_nothing_acknowledged() {
    let Some(admin) = pg::admin_url() else {
        return;
    };
    let Some(takes) = pg::vrm_takes(30) else {
        return;
    };
    let url = pg::fresh_db(&admin, "killed").await;
    let dir = tempfile::tempdir().unwrap();
    let (mut a, ha) = pg::spawn_replica(&url, dir.path());
    let acked = std::sync::Arc::new(std::sync::Mutex::new(Vec::<(i64, i64)>::new()));
    let acked2 = acked.clone();
    let client = std::thread::spawn(move || {
        for (name, body) in &takes {
            match support::exchange(ha, "POST", "/v1/motions", Some(body), Some(TOKEN)) {
                Ok((201, _, v)) => acked2.lock().unwrap().push((
                    v["motion_id"].as_i64().unwrap(),
                    v["windows"].as_i64().unwrap(),
                )),
                Ok((s, _, v)) => panic!("{name}: {s} {v}"),
                Err(_) => return, // the replica is gone
            }
        }
    });
    let t0 = Instant::now();
    while acked.lock().unwrap().len() < 5 {
        assert!(t0.elapsed() < Duration::from_secs(240), "ingest too slow");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(70));
    a.kill().unwrap(); // SIGKILL
    a.wait().unwrap();
    client.join().unwrap();
    let acked = acked.lock().unwrap().clone();
    println!("killed after {} acknowledged ingests", acked.len());

    let store = Store::open_at(&Location::Postgres(url), Some(dir.path()))
        .await
        .unwrap();
    let rows = store.motions().await.unwrap();
    for (id, windows) in &acked {
        assert!(rows.iter().any(|r| r.id == *id), "acknowledged {id} lost");
        assert_eq!(
            store.motion_windows(*id).await.unwrap().len() as i64,
            *windows
        );
    }
    // Whatever is stored is whole: acknowledged or not, every window has
    // each embedding made at ingest (PCA's come with the next refit, which
    // rewrites them all in one transaction).
    for r in &rows {
        let w = store.motion_windows(r.id).await.unwrap().len();
        assert!(w > 0, "motion {} has no windows", r.id);
        for kind in [
            choreo::features::Embedding::Stft,
            choreo::features::Embedding::Dct,
            choreo::features::Embedding::Pose,
        ] {
            assert_eq!(
                store.motion_embeddings(r.id, kind).await.unwrap().len(),
                w,
                "motion {} {}",
                r.id,
                kind.name()
            );
        }
    }
    assert!(rows.len() <= acked.len() + 1);
}
