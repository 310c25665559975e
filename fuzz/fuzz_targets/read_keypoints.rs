#![no_main]
//! Any bytes as a keypoint `.npy`, a keypoint JSON (both layouts) or WHAM-style
//! SMPL `.npz`: an error naming the file, or a valid motion — never a panic.
use choreo::motion::io::{read_bytes, ReadOptions};
use choreo::motion::keypoints::Layout;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let with = |layout: Option<Layout>| ReadOptions {
        keypoints: layout,
        fps: Some(30.0),
        ..Default::default()
    };
    for (name, opts) in [
        ("x.npy", with(Some(Layout::H36m17))),
        ("x.json", with(Some(Layout::Mediapipe33))),
        ("x.npz", with(None)),
    ] {
        if let Ok(l) = read_bytes(name, data, &opts) {
            let m = l.motion;
            if m.frames() * m.joints() < 100_000 {
                let _ = m.positions();
            }
        }
    }
});
