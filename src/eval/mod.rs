//! The thesis-table evaluations (`choreo eval …`): each reads a corpus,
//! runs one capability over it and returns rows the CLI prints as a table
//! or JSON.

pub mod footage;
pub mod generate;
pub mod interpolate;
pub mod keyframes;
pub mod query;
pub mod tokenize;

/// The `p` quantile (0..=1) of sorted values, nearest rank; NaN when empty.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}
