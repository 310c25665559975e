//! Where the real data lives: one setting, `CHOREO_DATA`, defaulting to
//! `../shared/data` from the project root. Nothing here is ever copied into
//! the repository.

use std::path::PathBuf;

/// The data root: `$CHOREO_DATA`, else `../shared/data` relative to the
/// crate (or the working directory when run elsewhere).
pub fn data_root() -> PathBuf {
    if let Some(p) = std::env::var_os("CHOREO_DATA") {
        return PathBuf::from(p);
    }
    let from_crate = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if from_crate.exists() {
        return from_crate;
    }
    PathBuf::from("../shared/data")
}

/// True when tests must fail rather than skip without the data
/// (`CHOREO_REQUIRE_DATA=1`, set by CI).
pub fn data_required() -> bool {
    std::env::var("CHOREO_REQUIRE_DATA").is_ok_and(|v| v == "1")
}

/// The data root if it holds `rel`; otherwise `None` after printing why the
/// caller skips — or a panic when the data is required.
pub fn require(rel: &str) -> Option<PathBuf> {
    let root = data_root();
    let p = root.join(rel);
    if p.exists() {
        return Some(p);
    }
    let msg = format!(
        "data not found at {} (set CHOREO_DATA to the folder holding aistpp/, bandai/, cmu/)",
        p.display()
    );
    if data_required() {
        panic!("CHOREO_REQUIRE_DATA=1 but {msg}");
    }
    eprintln!("SKIP: {msg}");
    None
}

/// All files under `dir` (recursive) with one of the extensions, sorted.
pub fn files_with_ext(dir: &std::path::Path, exts: &[&str]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| exts.iter().any(|x| x.eq_ignore_ascii_case(e)))
            {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// How many of a corpus's `n` sequences (sorted by a hash of their names)
/// are held out: `val_fraction` of them, at least one when there are two
/// or more, never all.
pub fn held_out_count(n: usize, val_fraction: f64) -> usize {
    if n < 2 {
        0
    } else {
        ((n as f64 * val_fraction).round() as usize).clamp(1, n - 1)
    }
}
