//! The `choreo` command line, split by area (the rest still lives in
//! `main.rs` and moves here piece by piece).

pub mod bench_index;
pub mod bench_model;
pub mod eval_generate;
pub mod footage;
pub mod token;

use anyhow::{Context, Result};

pub use choreo::service::percentile;

/// Rows of f32 as a 2-D `.npy` (written as f32).
pub fn write_npy_f32(path: &std::path::Path, rows: &[Vec<f32>]) -> Result<()> {
    let a = choreo::motion::io::npy::NdArray {
        shape: vec![rows.len(), rows.first().map_or(0, |r| r.len())],
        data: rows
            .iter()
            .flat_map(|r| r.iter().map(|&x| x as f64))
            .collect(),
    };
    std::fs::write(path, a.to_npy(true)).with_context(|| path.display().to_string())
}

/// This process's resident memory now and at its peak, MB (Linux).
pub fn rss_mb() -> (f64, f64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kb| kb.parse::<f64>().ok())
            .map_or(f64::NAN, |kb| kb / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}
