//! gRPC code generation without a system protoc: protox parses the .proto
//! files, tonic-prost-build writes the Rust types and service stubs.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=proto");
    let fds = protox::compile(["choreo/v1/choreo.proto"], ["proto"])?;
    tonic_prost_build::configure().compile_fds(fds)?;
    Ok(())
}
