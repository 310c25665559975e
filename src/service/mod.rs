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
