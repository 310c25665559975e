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

/// The corpus folders of the shared data, as they sit under its root.
pub const CORPUS_FOLDERS: [&str; 5] = ["aistpp", "aistpp-vrm", "bandai", "cmu", "amass"];

/// The key a motion is split by (held out or trained on): its SHA-256 is
/// what every split sorts by. A motion's name is its path as the caller
/// spelled it, so hashing the name made the split depend on where the data
/// lives and how its folder was written (`../shared/data` and
/// `/work/shared/data` held out different clips). The key is the path from
/// the last corpus folder of [`CORPUS_FOLDERS`] on, written under
/// `../shared/data/` as the bundled models' training saw it (so their
/// held-out clips stay held out); a file outside those folders is keyed by
/// its file name alone.
pub fn split_key(name: &str) -> String {
    let parts: Vec<&str> = name
        .split(['/', '\\'])
        .filter(|p| !p.is_empty() && *p != ".")
        .collect();
    match parts
        .iter()
        .rposition(|p| CORPUS_FOLDERS.contains(p))
        .filter(|&i| i + 1 < parts.len())
    {
        Some(i) => format!("../shared/data/{}", parts[i..].join("/")),
        None => parts.last().map_or(String::new(), |f| f.to_string()),
    }
}

/// The SHA-256 (hex) of a motion's [`split_key`].
pub fn split_hash(name: &str) -> String {
    crate::lm::manifest::sha256_hex(split_key(name).as_bytes())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_split_key_does_not_depend_on_how_the_data_folder_is_spelled() {
        let want = "../shared/data/aistpp-vrm/motions/gHO_sBM_cAll_d19_mHO3_ch02.pkl";
        for name in [
            want,
            "/work/shared/data/aistpp-vrm/motions/gHO_sBM_cAll_d19_mHO3_ch02.pkl",
            "/mnt/x//aistpp-vrm/./motions/gHO_sBM_cAll_d19_mHO3_ch02.pkl",
            "aistpp-vrm/motions/gHO_sBM_cAll_d19_mHO3_ch02.pkl",
        ] {
            assert_eq!(split_key(name), want, "{name}");
            assert_eq!(split_hash(name), split_hash(want), "{name}");
        }
        // The last corpus folder wins; outside the corpora, the file name.
        assert_eq!(
            split_key("/data/cmu/backup/bandai/take_01.bvh"),
            "../shared/data/bandai/take_01.bvh"
        );
        assert_eq!(split_key("/home/me/rehearsals/take_01.bvh"), "take_01.bvh");
        assert_eq!(split_key("take_01.bvh"), "take_01.bvh");
        // A folder named like a corpus as the last part is not a corpus path.
        assert_eq!(split_key("/x/y/bandai"), "bandai");
    }
}
