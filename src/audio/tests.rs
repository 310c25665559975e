//! Tests of `audio/mod.rs`.

use super::*;

#[test]
fn metronome_onsets_fall_on_the_beats() {
    for bpm in [80.0, 100.0, 120.0, 135.0] {
        let a = metronome(bpm, 10.0, 44_100).unwrap();
        let (_, f) = analyse(&a, "metronome").unwrap();
        // The click at t = 0 is already sounding in the first frame, so
        // it makes no rise (librosa finds none either): beats from the second.
        let beats: Vec<f64> = (1..)
            .map(|k| k as f64 * 60.0 / bpm * 60.0)
            .take_while(|&b| b < f.frames as f64 - 1.0)
            .collect();
        assert_eq!(f.peaks.len(), beats.len(), "{bpm}: {:?}", f.peaks);
        for (p, b) in f.peaks.iter().zip(&beats) {
            assert!(
                (*p as f64 - b).abs() <= 1.0,
                "{bpm} BPM: peak {p} vs beat {b}"
            );
        }
    }
}

#[test]
fn resampling_keeps_a_tone_and_drops_what_is_above_nyquist() {
    let sr = 44_100;
    let tone = |f: f64| -> Vec<f32> {
        (0..sr)
            .map(|i| (2.0 * std::f64::consts::PI * f * i as f64 / sr as f64).sin() as f32)
            .collect()
    };
    let rms = |x: &[f32]| {
        (x[2000..x.len() - 2000]
            .iter()
            .map(|v| (*v as f64).powi(2))
            .sum::<f64>()
            / (x.len() - 4000) as f64)
            .sqrt()
    };
    let kept = resample(&tone(1000.0), sr, SAMPLE_RATE);
    assert_eq!(kept.len(), SAMPLE_RATE as usize);
    assert!((rms(&kept) - 0.5f64.sqrt()).abs() < 0.01, "{}", rms(&kept));
    // 20 kHz is above the new Nyquist (15.36 kHz): it must vanish.
    let gone = resample(&tone(20_000.0), sr, SAMPLE_RATE);
    assert!(rms(&gone) < 0.01, "{}", rms(&gone));
}

#[test]
fn nmfd_separates_two_drums_by_their_spectra() {
    // Two "drums" with different spectra hit on alternating frames
    // (a kick every 10 frames, a hat every 10 frames offset by 5).
    let (t_n, f_n) = (200, 16);
    let mut v = vec![vec![0.0; f_n]; t_n];
    for t in 0..t_n {
        for tau in 0..3 {
            let decay = 0.5f64.powi(tau as i32);
            if t >= tau && (t - tau) % 10 == 0 {
                (0..4).for_each(|f| v[t][f] += decay);
            }
            if t >= tau && (t - tau) % 10 == 5 {
                (10..16).for_each(|f| v[t][f] += decay);
            }
        }
    }
    let h = nmfd(&v, 2, 4, 60, 1);
    // Each component's activation peaks on one drum's hits only.
    let on_kick = |row: &Vec<f64>| (0..t_n).step_by(10).map(|t| row[t]).sum::<f64>();
    let on_hat = |row: &Vec<f64>| (5..t_n).step_by(10).map(|t| row[t]).sum::<f64>();
    let (a, b) = (&h[0], &h[1]);
    let sep = (on_kick(a) - on_hat(a)).signum() != (on_kick(b) - on_hat(b)).signum();
    assert!(
        sep,
        "{:?} {:?}",
        (on_kick(a), on_hat(a)),
        (on_kick(b), on_hat(b))
    );
    let peaks = onset_peaks(&nmfd_like_sum(&h));
    assert!(peaks.len() >= 30, "{peaks:?}");
}

fn nmfd_like_sum(h: &[Vec<f64>]) -> Vec<f64> {
    let mut c = vec![0.0; h[0].len()];
    for row in h {
        let m = row.iter().copied().fold(0.0, f64::max);
        c.iter_mut().zip(row).for_each(|(x, v)| *x += v / m);
    }
    c
}

#[test]
fn bad_audio_is_a_clear_error() {
    assert!(decode(vec![], "x.wav", Some("wav"))
        .unwrap_err()
        .to_string()
        .contains("empty"));
    assert!(decode(
        b"RIFF\x00\x00\x00\x00WAVEjunk".to_vec(),
        "x.wav",
        Some("wav")
    )
    .is_err());
    assert!(decode(vec![7; 5000], "x.mp3", Some("mp3")).is_err());
    assert!(metronome(0.0, 1.0, 44_100).is_err() && metronome(10_000.0, 1.0, 44_100).is_err());
    let short = Audio {
        sample_rate: 44_100,
        samples: vec![0.0; 10],
        channels: 1,
    };
    assert!(analyse(&short, "short").is_err());
    // Silence analyses fine and has no onsets.
    let silent = Audio {
        sample_rate: 44_100,
        samples: vec![0.0; 44_100],
        channels: 2,
    };
    let (_, f) = analyse(&silent, "silent").unwrap();
    assert!(f.peaks.is_empty() && f.onset.iter().all(|&v| v == 0.0));
}
