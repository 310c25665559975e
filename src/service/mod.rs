//! Use cases, one file each. The CLI and (later) the HTTP/gRPC handlers call
//! these and only translate types.

pub mod eval_footage;
pub mod eval_generate;
pub mod eval_query;
pub mod eval_tokenize;
pub mod ingest;
pub mod interpolate;
pub mod keyframes;
pub mod query;

/// The `p` quantile (0..=1) of sorted values, nearest rank; NaN when empty.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}
