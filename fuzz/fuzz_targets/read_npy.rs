#![no_main]
//! The .npy parser on any bytes: Ok or Err, never a panic.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = choreo::motion::io::npy::parse_npy(data);
    let _ = choreo::motion::io::pickle::load(data);
});
