//! Tests of `features/interpolate.rs`.

use super::*;

fn sine(n: usize, f: f64, a: f64) -> Channels {
    (0..n)
        .map(|t| {
            std::array::from_fn(|c| {
                a * ((2.0 * std::f64::consts::PI * f * t as f64 / 60.0) + c as f64 * 0.1).sin()
                    * 0.5
            })
        })
        .collect()
}

#[test]
fn dct_round_trip_and_lowpass_of_a_slow_sine() {
    let x = sine(256, 0.5, 1.0);
    // Cutoff 128: keeps everything.
    let same = lowpass(&x, 128).unwrap();
    let err = x
        .iter()
        .zip(&same)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).abs()))
        .fold(0.0, f64::max);
    assert!(err < 1e-9, "{err}");
    // A 0.5 Hz sine survives a 1.875 Hz cutoff (coefficient 8 of 128)...
    let lp = lowpass(&x, 8).unwrap();
    let err = x
        .iter()
        .zip(&lp)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).abs()))
        .fold(0.0, f64::max);
    assert!(err < 0.1, "{err}");
    // ...a 10 Hz one does not.
    let fast = sine(256, 10.0, 1.0);
    let lp = lowpass(&fast, 8).unwrap();
    let rms =
        (lp.iter().flat_map(|r| r.iter().map(|v| v * v)).sum::<f64>() / (256.0 * 72.0)).sqrt();
    assert!(rms < 0.02, "{rms}");
}

#[test]
fn adam_matches_the_target_band() {
    let x = sine(200, 0.7, 0.8);
    let y = sine(220, 0.3, 1.2);
    let r = interpolate(
        &x,
        &y,
        &InterpolateOptions {
            steps: 400,
            ..Default::default()
        },
    )
    .unwrap();
    // Adam in the coefficient domain touches only the band, so it
    // reaches the closed-form optimum: the input with its band replaced.
    assert!(
        r.loss.last().unwrap() < &(r.loss[0] * 1e-3),
        "{:?}",
        &r.loss[r.loss.len() - 3..]
    );
    let want = dct_band_swap(&x, &y, (0, 8));
    let err = r
        .output
        .iter()
        .zip(&want)
        .flat_map(|(p, q)| p.iter().zip(q).map(|(u, v)| (u - v).abs()))
        .fold(0.0, f64::max);
    assert!(err < 0.02, "differs from the closed form by {err}");
}

/// The hand-derived gradients match finite differences.
#[test]
fn gradients_match_finite_differences() {
    let x = sine(160, 0.9, 0.7);
    let y = sine(160, 0.4, 1.1);
    for obj in Embedding::ALL {
        let opts = InterpolateOptions {
            objective: obj,
            steps: 1,
            band: (0, 16),
            ..Default::default()
        };
        // Build the objective through one interpolate call's setup by
        // probing loss differences directly.
        let o = objective_for(&x, &y, &opts);
        let probe = |xx: &Channels| -> f64 {
            let mut tmp = vec![[0.0; CHANNELS]; xx.len()];
            o.loss_grad(xx, &mut tmp)
        };
        let mut g = vec![[0.0; CHANNELS]; x.len()];
        let _ = o.loss_grad(&x, &mut g);
        for &(t, c) in &[(10usize, 3usize), (70, 40), (150, 71)] {
            let h = 1e-5;
            let mut xp = x.clone();
            xp[t][c] += h;
            let mut xm = x.clone();
            xm[t][c] -= h;
            let fd = (probe(&xp) - probe(&xm)) / (2.0 * h);
            assert!(
                (fd - g[t][c]).abs() < 1e-6 + 1e-3 * fd.abs(),
                "{obj:?} ({t},{c}): fd {fd} vs {}",
                g[t][c]
            );
        }
    }
}

fn objective_for(x: &Channels, y: &Channels, opts: &InterpolateOptions) -> Box<dyn Objective> {
    build_objective(x, y, opts).unwrap()
}
