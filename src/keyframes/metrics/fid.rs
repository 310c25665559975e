//! The Fréchet distance of two sets of feature vectors ([`fid`]) and
//! what a reader needs beside it: how far it moves with the clips drawn
//! ([`fid_range`]), the real-vs-real figure at a set's own size
//! ([`fid_same_size`]), and the features that make it ([`feature_gaps`]).

use crate::features::pca::{jacobi_eigen, matmul};

/// Fréchet distance between Gaussians fitted to two sets of feature vectors
/// (rows), every dimension standardised by the real set's mean and
/// standard deviation (dimensions with zero spread in the real set are
/// left unscaled).
pub fn fid(real: &[Vec<f64>], fake: &[Vec<f64>]) -> Option<f64> {
    let (a, b) = standardised(real, fake)?;
    Some(frechet(&a, &b))
}

/// Both sets scaled by the real set's per-dimension mean and standard
/// deviation ([`fid`]'s rule), or `None` when either set has under two
/// rows or the rows' lengths differ.
fn standardised(real: &[Vec<f64>], fake: &[Vec<f64>]) -> Option<(Vec<Vec<f64>>, Vec<Vec<f64>>)> {
    let d = real.first()?.len();
    if real.len() < 2 || fake.len() < 2 || fake.iter().chain(real).any(|r| r.len() != d) {
        return None;
    }
    let mu_r = mean(real, d);
    let sd: Vec<f64> = (0..d)
        .map(|k| {
            let v = real.iter().map(|r| (r[k] - mu_r[k]).powi(2)).sum::<f64>()
                / (real.len() - 1) as f64;
            if v > 1e-24 {
                v.sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let norm_set = |x: &[Vec<f64>]| -> Vec<Vec<f64>> {
        x.iter()
            .map(|r| (0..d).map(|k| (r[k] - mu_r[k]) / sd[k]).collect())
            .collect()
    };
    Some((norm_set(real), norm_set(fake)))
}

fn mean(x: &[Vec<f64>], d: usize) -> Vec<f64> {
    (0..d)
        .map(|k| x.iter().map(|r| r[k]).sum::<f64>() / x.len() as f64)
        .collect()
}

/// The sample covariance (row-major d × d) of rows about their mean `m`.
fn cov(x: &[Vec<f64>], m: &[f64]) -> Vec<f64> {
    let d = m.len();
    let mut c = vec![0.0; d * d];
    for r in x {
        for i in 0..d {
            let di = r[i] - m[i];
            for k in i..d {
                c[i * d + k] += di * (r[k] - m[k]);
            }
        }
    }
    for i in 0..d {
        for k in i..d {
            let v = c[i * d + k] / (x.len() - 1) as f64;
            c[i * d + k] = v;
            c[k * d + i] = v;
        }
    }
    c
}

/// The Fréchet distance of Gaussians fitted to two sets as they are (at
/// least two rows each, one length).
fn frechet(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let d = a[0].len();
    let (ma, mb) = (mean(a, d), mean(b, d));
    let (ca, cb) = (cov(a, &ma), cov(b, &mb));
    // Tr √(Ca Cb) = Σ √λ(√Ca Cb √Ca).
    let (va, ea) = jacobi_eigen(ca.clone(), d);
    let mut sq = vec![0.0; d * d];
    for i in 0..d {
        for k in 0..d {
            sq[i * d + k] = (0..d)
                .map(|m| ea[i * d + m] * va[m].max(0.0).sqrt() * ea[k * d + m])
                .sum();
        }
    }
    let mut mmat = matmul(&matmul(&sq, &cb, d), &sq, d);
    for i in 0..d {
        for k in i + 1..d {
            let s = 0.5 * (mmat[i * d + k] + mmat[k * d + i]);
            mmat[i * d + k] = s;
            mmat[k * d + i] = s;
        }
    }
    let (vm, _) = jacobi_eigen(mmat, d);
    let tr_sqrt: f64 = vm.iter().map(|v| v.max(0.0).sqrt()).sum();
    let tr_a: f64 = (0..d).map(|i| ca[i * d + i]).sum();
    let tr_b: f64 = (0..d).map(|i| cb[i * d + i]).sum();
    let dm: f64 = ma.iter().zip(&mb).map(|(x, y)| (x - y).powi(2)).sum();
    (dm + tr_a + tr_b - 2.0 * tr_sqrt).max(0.0)
}

/// The real set's first principal axis (its standardised features, as
/// [`fid`] scales them) and how a generated set sits along it. On motion
/// features this axis is a clip's overall activity, every joint's speed
/// at once (on Bandai it holds over half the real variance: takes that
/// run or dash against takes that stand and wave), and a generator that
/// makes only moderate clips loses most of its FID there.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// Unit vector over the features, signed so its loadings sum ≥ 0
    /// (up the axis = more of every feature).
    pub loadings: Vec<f64>,
    /// The axis's share of the real set's total standardised variance.
    pub real_share: f64,
    /// Variance along the axis: real, generated.
    pub real_var: f64,
    pub gen_var: f64,
    /// (generated mean − real mean) along the axis, in real standard
    /// deviations along it.
    pub shift: f64,
    /// The one-dimensional Fréchet term along the axis, in [`fid`]'s
    /// units: (mean difference)² + (√real_var − √gen_var)².
    pub cost: f64,
    /// [`fid`] with the axis projected out of both sets: what is left
    /// once the clips' activity is set aside.
    pub fid_without: f64,
}

/// [`Axis`] for a generated set against a real one (`None` as [`fid`]).
pub fn first_axis(real: &[Vec<f64>], gen: &[Vec<f64>]) -> Option<Axis> {
    let (a, b) = standardised(real, gen)?;
    let d = a[0].len();
    let ma = mean(&a, d);
    let (vals, vecs) = jacobi_eigen(cov(&a, &ma), d);
    let top = (0..d).max_by(|&i, &k| vals[i].total_cmp(&vals[k]))?;
    // jacobi_eigen's vectors are its matrix's columns.
    let mut v: Vec<f64> = (0..d).map(|i| vecs[i * d + top]).collect();
    if v.iter().sum::<f64>() < 0.0 {
        v.iter_mut().for_each(|x| *x = -*x);
    }
    let along = |x: &[Vec<f64>]| -> Vec<f64> {
        x.iter()
            .map(|r| r.iter().zip(&v).map(|(p, q)| p * q).sum())
            .collect()
    };
    let moments = |p: &[f64]| {
        let m = p.iter().sum::<f64>() / p.len() as f64;
        let var = p.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (p.len() - 1) as f64;
        (m, var)
    };
    let ((mr, vr), (mg, vg)) = (moments(&along(&a)), moments(&along(&b)));
    let total: f64 = vals.iter().map(|x| x.max(0.0)).sum();
    let off = |x: &[Vec<f64>]| -> Vec<Vec<f64>> {
        x.iter()
            .map(|r| {
                let p: f64 = r.iter().zip(&v).map(|(p, q)| p * q).sum();
                r.iter().zip(&v).map(|(x, q)| x - p * q).collect()
            })
            .collect()
    };
    Some(Axis {
        real_share: if total > 0.0 { vr / total } else { 0.0 },
        real_var: vr,
        gen_var: vg,
        shift: if vr > 1e-24 {
            (mg - mr) / vr.sqrt()
        } else {
            mg - mr
        },
        cost: (mg - mr).powi(2) + (vr.sqrt() - vg.sqrt()).powi(2),
        fid_without: frechet(&off(&a), &off(&b)),
        loadings: v,
    })
}

/// Bootstrap resamples behind [`fid_range`].
pub const FID_BOOTSTRAP: usize = 200;

/// The 5th and 95th percentiles of [`fid`] between `real` and resamples
/// (with replacement, the same count) of `gen`: how far the figure moves
/// with which generated samples happened to be drawn; a fixed seed, so a rerun
/// on the same clips prints the same range.
pub fn fid_range(real: &[Vec<f64>], gen: &[Vec<f64>]) -> Option<[f64; 2]> {
    use rand::{Rng, SeedableRng};
    if gen.len() < 2 {
        return None;
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(0x0F1D);
    let mut v: Vec<f64> = (0..FID_BOOTSTRAP)
        .filter_map(|_| {
            let pick: Vec<Vec<f64>> = (0..gen.len())
                .map(|_| gen[rng.gen_range(0..gen.len())].clone())
                .collect();
            fid(real, &pick).filter(|x| x.is_finite())
        })
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    Some([at(0.05), at(0.95)])
}

/// Draws behind [`fid_same_size`].
pub const FID_SAME_SIZE_DRAWS: usize = 50;

/// The real-vs-real yardstick at the generated set's size: the median of
/// [`fid`] between `real` and `n` rows drawn without replacement from
/// `pool` (another real set), over [`FID_SAME_SIZE_DRAWS`] draws (a fixed
/// seed). The Fréchet distance of a finite set is biased upward, the more
/// the fewer its rows, so a generated set of 90 clips compared with a real
/// yardstick of a thousand is judged against a figure it could not reach
/// even if it were real. `None` when the pool has fewer than `n` rows
/// (the yardstick would be the plain one) or `n < 2`.
pub fn fid_same_size(real: &[Vec<f64>], pool: &[Vec<f64>], n: usize) -> Option<f64> {
    same_size_by(real, pool, n, fid)
}

/// [`fid_same_size`] for any distance between two sets (the same draws):
/// the yardstick of a figure derived from [`fid`], such as
/// [`Axis::fid_without`].
pub fn same_size_by(
    real: &[Vec<f64>],
    pool: &[Vec<f64>],
    n: usize,
    dist: impl Fn(&[Vec<f64>], &[Vec<f64>]) -> Option<f64>,
) -> Option<f64> {
    use rand::seq::SliceRandom;
    use rand::SeedableRng;
    if n < 2 || pool.len() < n {
        return None;
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(0x5A3E);
    let mut idx: Vec<usize> = (0..pool.len()).collect();
    let mut v: Vec<f64> = (0..FID_SAME_SIZE_DRAWS)
        .filter_map(|_| {
            idx.shuffle(&mut rng);
            let pick: Vec<Vec<f64>> = idx[..n].iter().map(|&i| pool[i].clone()).collect();
            dist(real, &pick).filter(|x| x.is_finite())
        })
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// One feature's gap between a generated and a real set, in units of the
/// real spread: the mean's shift and the spread's ratio.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gap {
    pub feature: usize,
    /// (mean_gen − mean_real) / sd_real (unscaled where the real feature
    /// does not vary, as [`fid`] leaves it).
    pub z: f64,
    /// sd_gen / sd_real; where the real feature does not vary, sd_gen
    /// itself (unscaled), or 1 when neither varies.
    pub spread: f64,
    /// This feature's Fréchet distance on its own, in [`fid`]'s units:
    /// z² + (spread − 1)², or z² + sd_gen² where the real feature does not
    /// vary (its standardised real spread is then 0, not 1): the diagonal
    /// term the full [`fid`] would have were the features uncorrelated.
    pub cost: f64,
}

/// The `top` features that a generated set gets most wrong against a
/// real one, by [`Gap::cost`] (largest first): what drives a Fréchet
/// distance, feature by feature (a mean that moved, or a spread too
/// narrow or too wide).
pub fn feature_gaps(real: &[Vec<f64>], gen: &[Vec<f64>], top: usize) -> Vec<Gap> {
    let Some(d) = real.first().map(|r| r.len()) else {
        return Vec::new();
    };
    if real.len() < 2 || gen.len() < 2 || gen.iter().any(|r| r.len() != d) {
        return Vec::new();
    }
    let moments = |x: &[Vec<f64>], k: usize| {
        let m = x.iter().map(|r| r[k]).sum::<f64>() / x.len() as f64;
        let var = x.iter().map(|r| (r[k] - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64;
        (m, var.sqrt())
    };
    let mut gaps: Vec<Gap> = (0..d)
        .map(|k| {
            let (mr, sr) = moments(real, k);
            let (mg, sg) = moments(gen, k);
            // fid's rule: a real feature without spread is left unscaled.
            if sr > 1e-12 {
                let (z, spread) = ((mg - mr) / sr, sg / sr);
                let cost = z * z + (spread - 1.0).powi(2);
                Gap {
                    feature: k,
                    z,
                    spread,
                    cost,
                }
            } else {
                let z = mg - mr;
                Gap {
                    feature: k,
                    z,
                    spread: if sg > 1e-12 { sg } else { 1.0 },
                    cost: z * z + sg * sg,
                }
            }
        })
        .collect();
    gaps.sort_by(|a, b| b.cost.total_cmp(&a.cost));
    gaps.truncate(top);
    gaps
}
