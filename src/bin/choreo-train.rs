//! `choreo-train`: the offline trainer. For now it surveys a corpus — what a
//! training run would read — through the same readers the server uses.

use anyhow::Result;
use choreo::motion::io::{self, ReadOptions};
use clap::{Parser, Subcommand};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "choreo-train",
    version,
    about = "Offline trainer for choreo's motion models"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Read every motion file under DIR and summarise it by corpus: files,
    /// frames, seconds, unreadable files with their reasons.
    Survey {
        #[arg(long, env = "CHOREO_DATA")]
        data: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Survey { data, json } => {
            let files = choreo::data::files_with_ext(&data, &["pkl", "npz", "bvh"]);
            let mut by: BTreeMap<String, (usize, usize, f64)> = BTreeMap::new();
            let mut errors = Vec::new();
            for f in &files {
                match io::read_path(f, &ReadOptions::default()) {
                    Ok(l) => {
                        let m = l.motion;
                        let corpus = m.labels.get("corpus").cloned().unwrap_or_else(|| l.format.name().to_string());
                        let e = by.entry(corpus).or_default();
                        e.0 += 1;
                        e.1 += m.frames();
                        e.2 += m.duration_s();
                    }
                    Err(e) => errors.push(serde_json::json!({"file": f.display().to_string(), "reason": e.to_string()})),
                }
            }
            if json {
                let corpora: Vec<_> = by
                    .iter()
                    .map(|(k, v)| serde_json::json!({"corpus": k, "files": v.0, "frames": v.1, "seconds": v.2}))
                    .collect();
                println!(
                    "{}",
                    serde_json::json!({"corpora": corpora, "errors": errors})
                );
            } else {
                println!(
                    "{:<12} {:>6} {:>9} {:>9}",
                    "corpus", "files", "frames", "seconds"
                );
                for (k, v) in &by {
                    println!("{:<12} {:>6} {:>9} {:>9.1}", k, v.0, v.1, v.2);
                }
                for e in &errors {
                    println!("unreadable: {} — {}", e["file"], e["reason"]);
                }
            }
            Ok(())
        }
    }
}
