//! Use cases, one file each. The CLI and (later) the HTTP/gRPC handlers call
//! these and only translate types.

pub mod interpolate;
pub mod keyframes;
