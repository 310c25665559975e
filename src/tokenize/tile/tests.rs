//! Tests of `tokenize/tile.rs`.

use super::*;
use crate::tokenize::GeodesicError;

/// Smooth joint motion: each channel a sum of two slow sines with its
/// own phase, so PCA and the DCT both have something to compress.
fn smooth(frames: usize, channels: usize, seed: u64) -> Series {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let params: Vec<[f64; 4]> = (0..channels)
        .map(|_| std::array::from_fn(|_| rng.gen_range(0.0..1.0)))
        .collect();
    let mut data = Vec::new();
    for t in 0..frames {
        let x = t as f64 / 60.0;
        for p in &params {
            data.push(
                0.6 * p[0] * (2.0 * std::f64::consts::PI * (0.5 + p[1]) * x + 6.0 * p[2]).sin()
                    + 0.3 * (2.0 * std::f64::consts::PI * 2.0 * x + 6.0 * p[3]).sin(),
            );
        }
    }
    Series::new(channels, data).unwrap()
}

fn error(codec: &TileCodec, x: &Series) -> f64 {
    let y = codec
        .decode(&codec.encode(x).unwrap())
        .unwrap()
        .truncated(x.frames());
    GeodesicError::between(x, &y).mean
}

#[test]
fn error_shrinks_as_kept_coefficients_and_components_grow() {
    let x = smooth(600, 24, 1);
    let base = TileSettings {
        tile: 30,
        reduction: Reduction::Pca,
        components: 4,
        keep: 0.1,
        bins: 360,
    };
    // Bins finer than the number of fitted coefficients, so the
    // truncation is what is measured (with 360 bins the bins thin out as
    // more coefficients share them, and the error need not fall).
    let mut last = f64::INFINITY;
    for keep in [0.05, 0.1, 0.3, 0.6, 1.0] {
        let s = TileSettings {
            keep,
            components: 24,
            bins: 65_536,
            ..base
        };
        let c = TileCodec::fit(&[&x], s).unwrap();
        let e = error(&c, &x);
        assert!(e < last, "keep {keep}: {e} ≥ {last}");
        last = e;
    }
    let mut last = f64::INFINITY;
    for components in [1, 2, 4, 8, 16, 24] {
        let s = TileSettings {
            components,
            keep: 1.0,
            bins: 65_536,
            ..base
        };
        let c = TileCodec::fit(&[&x], s).unwrap();
        let e = error(&c, &x);
        assert!(e <= last * 1.0001, "D {components}: {e} > {last}");
        last = e;
    }
    // All components, all coefficients: only the quantisation is left.
    assert!(last < 1e-3, "{last}");
    // The same with 360 bins: small, but coarser.
    let c = TileCodec::fit(
        &[&x],
        TileSettings {
            components: 24,
            keep: 1.0,
            ..base
        },
    )
    .unwrap();
    assert!(error(&c, &x) < 0.05, "{}", error(&c, &x));
}

#[test]
fn ica_spans_the_pca_subspace_and_words_round_trip() {
    let x = smooth(300, 12, 2);
    for reduction in [Reduction::Pca, Reduction::Ica] {
        let s = TileSettings {
            tile: 15,
            reduction,
            components: 12,
            keep: 1.0,
            bins: 4096,
        };
        let c = TileCodec::fit(&[&x], s).unwrap();
        assert!(error(&c, &x) < 2e-3, "{reduction:?}: {}", error(&c, &x));
        let words = c.encode(&x).unwrap();
        assert_eq!(words.len(), 20);
        // Every kept coefficient is one symbol; full keep means no runs.
        assert!(words.iter().all(|w| w.len() == 12 * 15));
    }
    // A tenth kept: the zeros collapse into runs of at most a tile.
    let c = TileCodec::fit(
        &[&x],
        TileSettings {
            tile: 15,
            reduction: Reduction::Pca,
            components: 6,
            keep: 0.1,
            bins: 360,
        },
    )
    .unwrap();
    let words = c.encode(&x).unwrap();
    for w in &words {
        let kept = w.iter().filter(|&&s| s < 360).count();
        assert_eq!(kept, 9);
        let covered: usize = w
            .iter()
            .map(|&s| if s < 360 { 1 } else { (s - 359) as usize })
            .sum();
        assert_eq!(covered, 90);
        assert!(w.len() < 90);
    }
}

#[test]
fn malformed_words_are_errors() {
    let x = smooth(60, 6, 3);
    let c = TileCodec::fit(
        &[&x],
        TileSettings {
            tile: 10,
            reduction: Reduction::Pca,
            components: 3,
            keep: 0.5,
            bins: 16,
        },
    )
    .unwrap();
    let mut words = c.encode(&x).unwrap();
    assert!(c.decode(&words).is_ok());
    words[0].pop();
    assert!(c.decode(&words).is_err());
    assert!(c.decode(&[vec![99]]).is_err());
    assert!(c.decode(&[vec![16 + 9; 4]]).is_err());
    let bad = TileSettings {
        tile: 10,
        reduction: Reduction::Pca,
        components: 7,
        keep: 0.5,
        bins: 16,
    };
    assert!(TileCodec::fit(&[&x], bad).is_err());
    let bad = TileSettings {
        keep: 0.0,
        components: 3,
        ..bad
    };
    assert!(TileCodec::fit(&[&x], bad).is_err());
}
