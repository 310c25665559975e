#![no_main]
//! Any bytes: an error naming the file, or a valid motion — never a panic.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let opts = choreo::motion::io::ReadOptions::default();
    if let Ok(l) = choreo::motion::io::read_bytes("x.npz", data, &opts) {
        // Whatever loads must be usable: forward kinematics and a BVH write.
        let m = l.motion;
        if m.frames() * m.joints() < 100_000 {
            let _ = m.positions();
            let _ = choreo::motion::io::bvh::write_bvh(&m, &Default::default());
        }
    }
});
