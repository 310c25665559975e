//! Audio input: WAV in every common sample format, mono and stereo, a
//! metronome driving keyframe selection end to end, and bad files.

use choreo::audio::{analyse, decode, metronome};
use choreo::motion::{Labels, Motion, Skeleton};
use choreo::service::keyframes::{reconstruct, Inbetween, KeyframeRequest, Music, Select};

/// A WAV file: `format` 1 (integer PCM) or 3 (IEEE float).
fn wav(samples: &[f32], channels: u16, rate: u32, bits: u16, format: u16) -> Vec<u8> {
    let mut data = Vec::new();
    for &s in samples {
        for _ in 0..channels {
            match (format, bits) {
                (3, 32) => data.extend_from_slice(&s.to_le_bytes()),
                (1, 8) => data.push(((s * 127.0).round() as i16 + 128) as u8),
                (1, 16) => data.extend_from_slice(&((s * 32767.0).round() as i16).to_le_bytes()),
                (1, 24) => {
                    data.extend_from_slice(&((s * 8_388_607.0).round() as i32).to_le_bytes()[..3])
                }
                _ => unreachable!(),
            }
        }
    }
    let block = channels * bits / 8;
    let mut out = b"RIFF".to_vec();
    out.extend_from_slice(&(36 + data.len() as u32).to_le_bytes());
    out.extend_from_slice(b"WAVEfmt ");
    out.extend_from_slice(&16u32.to_le_bytes());
    out.extend_from_slice(&format.to_le_bytes());
    out.extend_from_slice(&channels.to_le_bytes());
    out.extend_from_slice(&rate.to_le_bytes());
    out.extend_from_slice(&(rate * block as u32).to_le_bytes());
    out.extend_from_slice(&block.to_le_bytes());
    out.extend_from_slice(&bits.to_le_bytes());
    out.extend_from_slice(b"data");
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(&data);
    out
}

#[test]
fn wav_in_every_sample_format_decodes_to_the_same_signal() {
    let x: Vec<f32> = (0..4410).map(|i| 0.5 * (i as f32 * 0.05).sin()).collect();
    for (bits, format, tol) in [(8, 1, 0.01), (16, 1, 1e-4), (24, 1, 1e-6), (32, 3, 1e-7)] {
        for channels in [1, 2] {
            let a = decode(
                wav(&x, channels, 22_050, bits, format),
                "t.wav",
                Some("wav"),
            )
            .unwrap_or_else(|e| panic!("{bits}-bit {channels} ch: {e}"));
            assert_eq!(
                (a.sample_rate, a.channels, a.samples.len()),
                (22_050, channels as usize, x.len())
            );
            let worst = a
                .samples
                .iter()
                .zip(&x)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f32::max);
            assert!(worst < tol, "{bits}-bit {channels} ch: {worst}");
        }
    }
}

#[test]
fn corrupt_and_degenerate_audio_are_clear_errors() {
    let x: Vec<f32> = vec![0.1; 1000];
    let good = wav(&x, 1, 44_100, 16, 1);
    // Truncated header, garbage, a zero sample rate.
    assert!(decode(good[..20].to_vec(), "t.wav", Some("wav")).is_err());
    assert!(decode(vec![0x55; 4096], "t.ogg", Some("ogg")).is_err());
    let mut zero_rate = good.clone();
    zero_rate[24..28].copy_from_slice(&0u32.to_le_bytes());
    let e = decode(zero_rate, "t.wav", Some("wav"));
    assert!(e.is_err(), "{e:?}");
    // Too short to analyse.
    let tiny = decode(wav(&x[..10], 1, 44_100, 16, 1), "t.wav", Some("wav")).unwrap();
    assert!(analyse(&tiny, "t.wav")
        .unwrap_err()
        .to_string()
        .contains("too short"));
    // Silence: analysis works, selection by onsets says why it cannot.
    let silent = decode(
        wav(&vec![0.0; 44_100 * 3], 2, 44_100, 16, 1),
        "s.wav",
        Some("wav"),
    )
    .unwrap();
    let (_, f) = analyse(&silent, "s.wav").unwrap();
    let m = still(180);
    let r = KeyframeRequest {
        select: Select::Onset,
        inbetween: Inbetween::Slerp,
        count: 4,
        music: Music::Audio(Box::new(f)),
    };
    assert!(reconstruct(&m, &r)
        .unwrap_err()
        .to_string()
        .contains("silent"));
}

fn still(frames: usize) -> Motion {
    let sk = Skeleton::smpl24();
    Motion::new(
        "still",
        60.0,
        sk,
        vec![[0.0; 3]; frames],
        vec![[0.0; 3]; frames * 24],
        Labels::new(),
    )
    .unwrap()
}

#[test]
fn a_metronome_puts_music_keyframes_on_its_beats() {
    // 120 BPM for 4 s: beats every 30 frames; the one at 0 is the first
    // keyframe anyway.
    let a = metronome(120.0, 4.0, 48_000).unwrap();
    let (_, f) = analyse(&a, "metronome").unwrap();
    let r = KeyframeRequest {
        select: Select::Onset,
        inbetween: Inbetween::Slerp,
        count: 9,
        music: Music::Audio(Box::new(f)),
    };
    let (_, rep) = reconstruct(&still(240), &r).unwrap();
    assert_eq!(rep.keyframes.len(), 9);
    for (k, want) in rep.keyframes[1..8]
        .iter()
        .zip([30, 60, 90, 120, 150, 180, 210])
    {
        assert!((*k as i64 - want).abs() <= 1, "{:?}", rep.keyframes);
    }
}
