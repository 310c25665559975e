//! What every bundled model folder (`models/*`) promises a user who
//! downloads it (#15): at most 25 MB, a licence for every corpus that
//! touched its weights, its training time, and no machine paths.

use std::path::Path;

fn folders() -> Vec<std::path::PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut out: Vec<_> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("manifest.json").is_file())
        .collect();
    out.sort();
    out
}

#[test]
fn every_bundled_model_is_small_licensed_timed_and_path_free() {
    let dirs = folders();
    assert!(dirs.len() >= 3, "{dirs:?}");
    for dir in dirs {
        let name = dir.file_name().unwrap().to_string_lossy().to_string();
        let bytes: u64 = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().metadata().unwrap().len())
            .sum();
        assert!(bytes <= 25_000_000, "{name}: {bytes} bytes");
        let text = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
        for p in ["/tmp/", "/work/", "/home/", "/root/", "/Users/", ":\\\\"] {
            assert!(
                !text.contains(p),
                "{name}: manifest holds a machine path ({p})"
            );
        }
        let m: serde_json::Value = serde_json::from_str(&text).unwrap();
        let licences: Vec<&str> = m["data"]["licences"]
            .as_array()
            .unwrap_or_else(|| panic!("{name}: no data.licences"))
            .iter()
            .map(|l| l.as_str().unwrap())
            .collect();
        for c in m["data"]["corpora"].as_array().unwrap() {
            let c = c.as_str().unwrap();
            assert!(
                licences.iter().any(|l| l.starts_with(&format!("{c}:"))),
                "{name}: no licence for corpus {c}: {licences:?}"
            );
        }
        // A parent's licences (where its record lists them) are the
        // child's too, all the way up.
        let mut parent = &m["training"]["parent"];
        while !parent.is_null() {
            for l in parent["data"]["licences"].as_array().into_iter().flatten() {
                let l = l.as_str().unwrap();
                assert!(
                    licences.contains(&l),
                    "{name}: parent's licence {l:?} missing"
                );
            }
            parent = &parent["parent"];
        }
        let t = &m["training"];
        let seconds = [
            &m["metrics"]["train_seconds"],
            &t["train_seconds"],
            &t["seconds"],
            &t["total_train_seconds"],
            &t["total_seconds"],
        ]
        .iter()
        .filter_map(|v| v.as_f64())
        .fold(0.0f64, f64::max);
        assert!(seconds > 0.0, "{name}: no training time recorded");
        eprintln!(
            "{name}: {bytes} bytes, {} licences, trained {seconds:.0} s",
            licences.len()
        );
    }
}
