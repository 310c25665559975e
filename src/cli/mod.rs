//! The `choreo` command line, split by area: `args` (the commands and
//! shared options), `archive` (ingest, query), `motion` (inspect, convert,
//! positions, interpolate, lowpass, keyframes), `bench`, `eval`, `dev`,
//! `footage`, `token`; `main.rs` keeps only the allocator and `main`.

pub mod archive;
pub mod args;
pub mod bench;
pub mod bench_index;
pub mod bench_model;
pub mod dev;
pub mod eval;
pub mod eval_generate;
pub mod exemplars;
pub mod footage;
pub mod motion;
pub mod postures;
pub mod token;

use anyhow::{Context, Result};

pub use choreo::eval::percentile;

/// Rows of f32 as a 2-D `.npy` (written as f32).
pub fn write_npy_f32<'a>(
    path: &std::path::Path,
    dim: usize,
    rows: impl ExactSizeIterator<Item = &'a [f32]>,
) -> Result<()> {
    use std::io::Write;
    let ctx = || path.display().to_string();
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).with_context(ctx)?);
    f.write_all(&choreo::motion::io::npy::npy_header(
        &[rows.len(), dim],
        true,
    ))
    .with_context(ctx)?;
    for r in rows {
        anyhow::ensure!(
            r.len() == dim,
            "{}: a row of {} values, not {dim}",
            ctx(),
            r.len()
        );
        for x in r {
            f.write_all(&x.to_le_bytes()).with_context(ctx)?;
        }
    }
    f.flush().with_context(ctx)
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

/// Run one command line.
pub fn run(cli: args::Cli) -> anyhow::Result<()> {
    use args::Cmd;
    match cli.cmd {
        Cmd::Inspect(a) => motion::inspect_cmd(a),
        Cmd::Convert(a) => motion::convert_cmd(a),
        Cmd::Positions(a) => motion::positions_cmd(a),
        Cmd::Dev { cmd } => dev::run(cmd),
        Cmd::Ingest(a) => archive::ingest_cmd(a),
        Cmd::Query(a) => archive::query_cmd(a),
        Cmd::Interpolate(a) => motion::interpolate_run(a),
        Cmd::Lowpass(a) => motion::lowpass_cmd(a),
        Cmd::Bench { cmd } => bench::run(cmd),
        Cmd::Eval { cmd } => eval::run(cmd),
        Cmd::Exemplars(a) => exemplars::run(a),
        Cmd::Postures(a) => postures::run(a),
        Cmd::Footage { cmd } => footage::run(cmd),
        Cmd::Token { cmd } => token::run(cmd),
        Cmd::Serve(cfg) => {
            choreo::server::init_logging(cfg.log_format);
            runtime()?.block_on(choreo::server::serve(cfg))
        }
        Cmd::Keyframes(a) => motion::keyframes_run(a),
    }
}

pub fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}

pub fn parse_pairs(flag: &str, items: &[String]) -> Result<Vec<(String, String)>> {
    items
        .iter()
        .map(|f| {
            f.split_once('=')
                .filter(|(a, b)| !a.is_empty() && !b.is_empty())
                .map(|(a, b)| (a.to_string(), b.to_string()))
                .with_context(|| format!("{flag}: '{f}' is not KIND=VALUE"))
        })
        .collect()
}
