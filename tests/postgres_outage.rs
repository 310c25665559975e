//! PostgreSQL restarted under load (needs `CHOREO_TEST_POSTGRES` and
//! `CHOREO_TEST_POSTGRES_RESTART`, a shell command that stops that
//! server and starts it again, e.g. `scripts/pg_throwaway.sh restart DIR
//! 2` (down for 2 s); `.ci/run` sets both). Two replicas: A takes ingests, B answers queries; the database
//! restarts mid-load. Every answer is a success or 503 (never another
//! error), every acknowledged write is there afterwards, and both replicas
//! serve again by themselves, without a restart. Its own test binary: no
//! other test's database goes away under it.

mod support;

use std::time::{Duration, Instant};
use support::pg::{self, TOKEN};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn database_restart_gives_503_then_recovers_with_nothing_lost() {
    let Some(admin) = pg::admin_url() else {
        return;
    };
    let restart = match std::env::var("CHOREO_TEST_POSTGRES_RESTART") {
        Ok(c) if !c.is_empty() => c,
        _ => {
            let why =
                "CHOREO_TEST_POSTGRES_RESTART is not set (a command that restarts the test server)";
            if std::env::var("CHOREO_REQUIRE_POSTGRES").is_ok_and(|v| v == "1") {
                panic!("CHOREO_REQUIRE_POSTGRES=1 but {why}");
            }
            eprintln!("SKIP: {why}");
            return;
        }
    };
    let Some(takes) = pg::vrm_takes(24) else {
        return;
    };
    let url = pg::fresh_db(&admin, "outage").await;
    let (da, db) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (a, ha) = pg::spawn_replica(&url, da.path());
    let (b, hb) = pg::spawn_replica(&url, db.path());
    let out = tokio::task::spawn_blocking(move || {
        let post = |body: &serde_json::Value| {
            support::exchange(ha, "POST", "/v1/motions", Some(body), Some(TOKEN))
                .map(|(s, _, v)| (s, v))
                .unwrap_or((0, serde_json::Value::Null))
        };
        let (s, v) = post(&takes[0].1);
        assert_eq!(s, 201, "{v}");
        let first = v["motion_id"].as_i64().unwrap();
        let mut acked = vec![first];
        let mut statuses = std::collections::BTreeMap::<u16, usize>::new();
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let stop2 = stop.clone();
        let reader = std::thread::spawn(move || {
            let mut seen = std::collections::BTreeMap::<u16, usize>::new();
            while !stop2.load(std::sync::atomic::Ordering::Relaxed) {
                *seen.entry(pg::top_hit(hb, first).0).or_default() += 1;
                std::thread::sleep(Duration::from_millis(5));
            }
            seen
        });
        let mut restarter = None;
        for (i, (name, body)) in takes[1..].iter().enumerate() {
            if i == 4 {
                // Mid-load: the database goes away and comes back, while
                // the writes and reads go on.
                let cmd = restart.clone();
                restarter = Some(std::thread::spawn(move || {
                    let t0 = Instant::now();
                    let ok = std::process::Command::new("sh")
                        .args(["-c", &cmd])
                        .status()
                        .unwrap()
                        .success();
                    assert!(ok, "{cmd} failed");
                    t0.elapsed()
                }));
            }
            // A client retries a 503 (as Retry-After / UNAVAILABLE ask).
            loop {
                let (s, v) = post(body);
                *statuses.entry(s).or_default() += 1;
                match s {
                    201 | 200 => {
                        acked.push(v["motion_id"].as_i64().unwrap());
                        break;
                    }
                    503 => std::thread::sleep(Duration::from_millis(200)),
                    other => panic!("{name}: {other} {v}"),
                }
            }
        }
        let restarted = restarter.map(|r| r.join().unwrap());
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let reads = reader.join().unwrap();
        // Both replicas serve again by themselves; everything acked is there.
        let t0 = Instant::now();
        for h in [ha, hb] {
            loop {
                let (s, _, v) = support::exchange(h, "GET", "/v1/motions", None, None).unwrap();
                if s == 200 && v["motions"].as_array().unwrap().len() == acked.len() {
                    break;
                }
                assert!(t0.elapsed() < Duration::from_secs(30), "{s} {v}");
                std::thread::sleep(Duration::from_millis(100));
            }
            let last = *acked.last().unwrap();
            let t1 = Instant::now();
            while pg::top_hit(h, last) != (200, Some(last)) {
                assert!(
                    t1.elapsed() < Duration::from_secs(30),
                    "replica never recovered"
                );
                std::thread::sleep(Duration::from_millis(50));
            }
        }
        (statuses, reads, restarted, acked.len())
    })
    .await
    .unwrap();
    let (writes, reads, restarted, acked) = out;
    println!(
        "database down and up in {:?}; writes {writes:?}; reads {reads:?}; {acked} acknowledged, all present",
        restarted.unwrap()
    );
    for s in writes.keys().chain(reads.keys()) {
        assert!(
            matches!(s, 200 | 201 | 503),
            "status {s}: {writes:?} {reads:?}"
        );
    }
    pg::kill(a);
    pg::kill(b);
}
