//! The `choreo` command line, split by area (the rest still lives in
//! `main.rs` and moves here piece by piece).

pub mod eval_generate;
