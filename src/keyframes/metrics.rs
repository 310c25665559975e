//! Reconstruction metrics on forward-kinematics joint positions (thesis 001
//! §2.8, §3.6; SPEC §6). Positions are `[frames][joints]` in metres, y up.
//!
//! - [`mse`]: Eq. 2.8, mean over frames and joints of the squared distance.
//! - [`kinetic_features`]: the 72-d kinetic features AIST++'s evaluation uses
//!   (per SMPL joint: mean horizontal and vertical kinetic energy of the
//!   5-frame-window average velocity, and mean acceleration magnitude).
//!   AIST++'s code divides only the earlier position by the frame time in
//!   its acceleration (an operator-precedence slip, which makes that term
//!   mostly position); we compute the acceleration as written in its
//!   formula, so our FID_k is not numerically comparable with theirs.
//! - [`geometric_features`]: the 32 boolean Müller-style features of
//!   AIST++'s evaluation, averaged over frames. Their velocity thresholds
//!   assume a 1/120 s frame time (kept as defined) and their body-size
//!   thresholds scale with the humerus length, shoulder and hip width — here
//!   taken from the SMPL rest skeleton.
//! - [`fid`]: Fréchet distance between two sets of feature vectors, each
//!   dimension standardised by the real set's mean and standard deviation.
//! - [`beat_alignment`]: both directions, see its docs.

use crate::features::reflect_index;
use crate::motion::rotation::{cross, dot, norm, sub, Vec3};
use crate::motion::{Motion, Skeleton};

mod fid;
pub use fid::*;

/// Eq. 2.8: mean over frames and joints of |x − x̂|², in m².
pub fn mse(a: &[Vec3], b: &[Vec3]) -> f64 {
    let n = a.len().min(b.len()).max(1);
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            let d = sub(*p, *q);
            dot(d, d)
        })
        .sum::<f64>()
        / n as f64
}

/// Per-frame squared error averaged over joints (m²).
pub fn per_frame_error(a: &[Vec3], b: &[Vec3], joints: usize) -> Vec<f64> {
    a.chunks(joints)
        .zip(b.chunks(joints))
        .map(|(x, y)| mse(x, y))
        .collect()
}

fn window_velocity(p: &[Vec3], j: usize, joints: usize, i: usize, dt: f64) -> Vec3 {
    let n = p.len() / joints;
    let (mut v, mut c) = ([0.0; 3], 0.0);
    for o in -2i64..=2 {
        let t = i as i64 + o;
        if t - 1 < 0 || t >= n as i64 {
            continue;
        }
        let d = sub(p[t as usize * joints + j], p[(t as usize - 1) * joints + j]);
        v = [v[0] + d[0], v[1] + d[1], v[2] + d[2]];
        c += 1.0;
    }
    [v[0] / (c * dt), v[1] / (c * dt), v[2] / (c * dt)]
}

fn window_acceleration(p: &[Vec3], j: usize, joints: usize, i: usize, dt: f64) -> f64 {
    let n = p.len() / joints;
    let (mut a, mut c) = ([0.0; 3], 0.0);
    for o in -2i64..=2 {
        let t = i as i64 + o;
        if t - 1 < 0 || t + 1 >= n as i64 {
            continue;
        }
        let t = t as usize;
        for k in 0..3 {
            let v2 = (p[(t + 1) * joints + j][k] - p[t * joints + j][k]) / dt;
            let v1 = (p[t * joints + j][k] - p[(t - 1) * joints + j][k]) / dt;
            a[k] += (v2 - v1) / dt;
        }
        c += 1.0;
    }
    if c == 0.0 {
        0.0
    } else {
        norm([a[0] / c, a[1] / c, a[2] / c])
    }
}

/// 3 values per joint: mean horizontal KE, mean vertical KE (of the
/// window-averaged velocity, per unit mass, ×2), mean acceleration norm.
pub fn kinetic_features(p: &[Vec3], joints: usize, fps: f64) -> Vec<f64> {
    let n = p.len() / joints.max(1);
    let dt = 1.0 / fps;
    let mut out = Vec::with_capacity(3 * joints);
    let denom = (n as f64 - 1.0).max(1.0);
    for j in 0..joints {
        let (mut h, mut v, mut e) = (0.0, 0.0, 0.0);
        for i in 1..n {
            let w = window_velocity(p, j, joints, i, dt);
            h += w[0] * w[0] + w[2] * w[2];
            v += w[1] * w[1];
            e += window_acceleration(p, j, joints, i, dt);
        }
        out.extend([h / denom, v / denom, e / denom]);
    }
    out
}

/// SMPL-24 joint indices used by the geometric features.
mod j {
    pub const ROOT: usize = 0;
    pub const LHIP: usize = 1;
    pub const RHIP: usize = 2;
    pub const BELLY: usize = 3;
    pub const LKNEE: usize = 4;
    pub const RKNEE: usize = 5;
    pub const LANKLE: usize = 7;
    pub const RANKLE: usize = 8;
    pub const CHEST: usize = 9;
    pub const LTOES: usize = 10;
    pub const RTOES: usize = 11;
    pub const NECK: usize = 12;
    pub const LSHOULDER: usize = 16;
    pub const RSHOULDER: usize = 17;
    pub const LELBOW: usize = 18;
    pub const RELBOW: usize = 19;
    pub const LWRIST: usize = 20;
    pub const RWRIST: usize = 21;
}

/// The geometric feature count.
pub const GEOMETRIC_DIMS: usize = 32;

/// The 32 boolean features per frame (from the second frame on), averaged
/// over frames. Needs SMPL-24 positions.
pub fn geometric_features(p: &[Vec3], joints: usize) -> Vec<f64> {
    assert_eq!(joints, 24, "geometric features are defined on SMPL-24");
    let rest = Motion::rest_positions(&Skeleton::smpl24());
    let dist = |a: usize, b: usize| norm(sub(rest[a], rest[b]));
    let hl = dist(j::LSHOULDER, j::LELBOW);
    let sw = dist(j::LSHOULDER, j::RSHOULDER);
    let hw = dist(j::LHIP, j::RHIP);
    let n = p.len() / 24;
    let tpf = 1.0 / 120.0;
    let mut sum = vec![0.0; GEOMETRIC_DIMS];
    for t in 1..n {
        let cur = |k: usize| p[t * 24 + k];
        let prv = |k: usize| p[(t - 1) * 24 + k];
        let y_min = [
            0.0,
            (0..24).map(|k| cur(k)[1]).fold(f64::INFINITY, f64::min),
            0.0,
        ];
        let zero = [0.0, 0.0, 0.0];
        let y_up = [0.0, 1.0, 0.0];
        let y_down = [0.0, -1.0, 0.0];
        let unit = |v: Vec3| {
            let l = norm(v);
            if l > 0.0 {
                [v[0] / l, v[1] / l, v[2] / l]
            } else {
                [0.0; 3]
            }
        };
        // Velocity of `q` relative to `a` (per 1/120 s) along `dir`.
        let rel_vel = |a: usize, q: usize, dir: Vec3| {
            let v = sub(sub(cur(q), cur(a)), sub(prv(q), prv(a)));
            dot(v, unit(dir)) / tpf
        };
        // f_move(j1, j2, j3): j3's velocity relative to j1 along j2 − j1.
        let f_move =
            |a: usize, b: usize, q: usize, th: f64| rel_vel(a, q, sub(cur(b), cur(a))) > th;
        // f_nmove(j1, j2, j3, j4): j4's velocity relative to j1 along
        // (j3 − j1) × (j2 − j1).
        let f_nmove = |a: usize, b: usize, c: usize, q: usize, th: f64| {
            rel_vel(a, q, cross(sub(cur(c), cur(a)), sub(cur(b), cur(a)))) > th
        };
        // Signed distance of q from the plane through a, b, c (normal
        // (c − a) × (b − a)).
        let f_plane = |a: Vec3, b: Vec3, c: Vec3, q: Vec3, th: f64| {
            dot(unit(cross(sub(c, a), sub(b, a))), sub(q, a)) > th
        };
        // Distance of q from the plane through `a` with normal n2 − n1.
        let f_nplane =
            |n1: Vec3, n2: Vec3, a: Vec3, q: Vec3, th: f64| dot(unit(sub(n2, n1)), sub(q, a)) > th;
        let angle = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| {
            let (u, v) = (sub(b, a), sub(d, c));
            let cos = dot(u, v) / (norm(u) * norm(v)).max(1e-300);
            cos.clamp(-1.0, 1.0).acos().to_degrees()
        };
        let f_angle = |a: Vec3, b: Vec3, c: Vec3, d: Vec3, lo: f64, hi: f64| {
            let x = angle(a, b, c, d);
            x > lo && x < hi
        };
        let f_fast = |q: usize, th: f64| norm(sub(cur(q), prv(q))) / tpf > th;
        let c = cur;
        let f = [
            f_nmove(j::NECK, j::RHIP, j::LHIP, j::RWRIST, 1.8 * hl),
            f_nmove(j::NECK, j::LHIP, j::RHIP, j::LWRIST, 1.8 * hl),
            f_nplane(c(j::CHEST), c(j::NECK), c(j::NECK), c(j::RWRIST), 0.2 * hl),
            f_nplane(c(j::CHEST), c(j::NECK), c(j::NECK), c(j::LWRIST), 0.2 * hl),
            f_move(j::BELLY, j::CHEST, j::CHEST, 1.8 * hl),
            f_move(j::BELLY, j::CHEST, j::CHEST, 1.8 * hl),
            f_angle(
                c(j::RELBOW),
                c(j::RSHOULDER),
                c(j::RELBOW),
                c(j::RWRIST),
                0.0,
                110.0,
            ),
            f_angle(
                c(j::LELBOW),
                c(j::LSHOULDER),
                c(j::LELBOW),
                c(j::LWRIST),
                0.0,
                110.0,
            ),
            f_nplane(
                c(j::LSHOULDER),
                c(j::RSHOULDER),
                c(j::LWRIST),
                c(j::RWRIST),
                2.5 * sw,
            ),
            f_move(j::LWRIST, j::RWRIST, j::RWRIST, 1.4 * hl),
            f_move(j::RWRIST, j::ROOT, j::LWRIST, 1.4 * hl),
            f_move(j::LWRIST, j::ROOT, j::RWRIST, 1.4 * hl),
            f_fast(j::RWRIST, 2.5 * hl),
            f_fast(j::LWRIST, 2.5 * hl),
            f_plane(c(j::ROOT), c(j::LHIP), c(j::LTOES), c(j::RANKLE), 0.38 * hl),
            f_plane(c(j::ROOT), c(j::RHIP), c(j::RTOES), c(j::LANKLE), 0.38 * hl),
            f_nplane(zero, y_up, y_min, c(j::RANKLE), 1.2 * hl),
            f_nplane(zero, y_up, y_min, c(j::LANKLE), 1.2 * hl),
            f_nplane(c(j::LHIP), c(j::RHIP), c(j::LANKLE), c(j::RANKLE), 2.1 * hw),
            f_angle(
                c(j::RKNEE),
                c(j::RHIP),
                c(j::RKNEE),
                c(j::RANKLE),
                0.0,
                110.0,
            ),
            f_angle(
                c(j::LKNEE),
                c(j::LHIP),
                c(j::LKNEE),
                c(j::LANKLE),
                0.0,
                110.0,
            ),
            f_fast(j::RANKLE, 2.5 * hl),
            f_fast(j::LANKLE, 2.5 * hl),
            f_angle(
                c(j::NECK),
                c(j::ROOT),
                c(j::RSHOULDER),
                c(j::RELBOW),
                25.0,
                180.0,
            ),
            f_angle(
                c(j::NECK),
                c(j::ROOT),
                c(j::LSHOULDER),
                c(j::LELBOW),
                25.0,
                180.0,
            ),
            f_angle(c(j::NECK), c(j::ROOT), c(j::RHIP), c(j::RKNEE), 50.0, 180.0),
            f_angle(c(j::NECK), c(j::ROOT), c(j::LHIP), c(j::LKNEE), 50.0, 180.0),
            f_plane(c(j::RANKLE), c(j::NECK), c(j::LANKLE), c(j::ROOT), 0.5 * hl),
            f_angle(c(j::NECK), c(j::ROOT), zero, y_up, 70.0, 110.0),
            f_nplane(zero, y_down, y_min, c(j::RWRIST), -1.2 * hl),
            f_nplane(zero, y_down, y_min, c(j::LWRIST), -1.2 * hl),
            f_fast(j::ROOT, 2.3 * hl),
        ];
        for (s, &b) in sum.iter_mut().zip(f.iter()) {
            *s += b as u8 as f64;
        }
    }
    let d = (n as f64 - 1.0).max(1.0);
    sum.iter().map(|s| s / d).collect()
}

/// Kinematic beats: local minima of the mean joint speed after a Gaussian
/// smoothing of σ = 5 frames (as AIST++'s evaluation finds them).
pub fn motion_beats(p: &[Vec3], joints: usize) -> Vec<usize> {
    let n = p.len() / joints.max(1);
    if n < 3 {
        return vec![];
    }
    let speed: Vec<f64> = (0..n)
        .map(|t| {
            let (a, b) = (t.saturating_sub(1), if t == 0 { 1 } else { t });
            (0..joints)
                .map(|k| norm(sub(p[b * joints + k], p[a * joints + k])))
                .sum::<f64>()
                / joints as f64
        })
        .collect();
    let s = gaussian_smooth(&speed, 5.0);
    (1..n - 1)
        .filter(|&t| s[t] < s[t - 1] && s[t] < s[t + 1])
        .collect()
}

/// Gaussian smoothing with reflected edges, truncated at 4σ.
pub fn gaussian_smooth(x: &[f64], sigma: f64) -> Vec<f64> {
    let r = (4.0 * sigma).ceil() as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ws: f64 = w.iter().sum();
    (0..x.len() as i64)
        .map(|t| {
            (-r..=r)
                .zip(&w)
                .map(|(k, wk)| wk * x[reflect_index(t + k, x.len())])
                .sum::<f64>()
                / ws
        })
        .collect()
}

/// Beat alignment, σ = 3 frames, both directions:
/// `music_to_motion` = mean over music beats of exp(−d²/2σ²), d the
/// distance to the nearest kinematic beat (the code of Bailando and of the
/// AIST++ metric scripts); `motion_to_music` = the same over kinematic
/// beats to the nearest music beat (the AIST++ paper's wording). `None`
/// when either list is empty.
pub fn beat_alignment(music: &[usize], motion: &[usize], sigma: f64) -> Option<(f64, f64)> {
    if music.is_empty() || motion.is_empty() {
        return None;
    }
    let score = |from: &[usize], to: &[usize]| {
        from.iter()
            .map(|&a| {
                let d = to
                    .iter()
                    .map(|&b| (a as f64 - b as f64).abs())
                    .fold(f64::INFINITY, f64::min);
                (-d * d / (2.0 * sigma * sigma)).exp()
            })
            .sum::<f64>()
            / from.len() as f64
    };
    Some((score(music, motion), score(motion, music)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fid_of_identical_sets_is_zero_and_grows_with_a_shift() {
        let a: Vec<Vec<f64>> = (0..50)
            .map(|i| {
                vec![
                    (i as f64 * 0.37).sin(),
                    (i as f64 * 0.11).cos(),
                    i as f64 * 0.01,
                ]
            })
            .collect();
        assert!(fid(&a, &a).unwrap() < 1e-9);
        let shifted: Vec<Vec<f64>> = a
            .iter()
            .map(|r| r.iter().map(|v| v + 0.5).collect())
            .collect();
        let f1 = fid(&a, &shifted).unwrap();
        let more: Vec<Vec<f64>> = a
            .iter()
            .map(|r| r.iter().map(|v| v + 1.0).collect())
            .collect();
        let f2 = fid(&a, &more).unwrap();
        assert!(f1 > 0.1 && f2 > 3.0 * f1, "{f1} {f2}");
        assert!(fid(&a[..1], &a).is_none());
    }

    #[test]
    fn same_size_yardstick_shows_the_small_set_bias_and_gaps_name_what_moved() {
        use rand::{Rng, SeedableRng};
        // Two sets from one 6-d distribution: a small one scores worse
        // against the reference than a large one, though both are real.
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut draw = |n: usize| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| (0..6).map(|_| rng.gen::<f64>() * 2.0 - 1.0).collect())
                .collect()
        };
        let (real, pool) = (draw(60), draw(600));
        let whole = fid(&real, &pool).unwrap();
        let small = fid_same_size(&real, &pool, 20).unwrap();
        assert!(small > 1.5 * whole, "{small} vs {whole}");
        // Too few rows in the pool: no same-size figure.
        assert!(fid_same_size(&real, &pool[..10], 20).is_none());
        assert!(fid_same_size(&real, &pool, 1).is_none());
        // Feature 4 shifted by one real spread: named first, z ≈ +1.
        let sd = {
            let m = real.iter().map(|r| r[4]).sum::<f64>() / 60.0;
            (real.iter().map(|r| (r[4] - m).powi(2)).sum::<f64>() / 59.0).sqrt()
        };
        let moved: Vec<Vec<f64>> = real
            .iter()
            .map(|r| {
                let mut r = r.clone();
                r[4] += sd;
                r
            })
            .collect();
        let gaps = feature_gaps(&real, &moved, 2);
        assert_eq!(gaps.len(), 2);
        assert_eq!(gaps[0].feature, 4);
        assert!((gaps[0].z - 1.0).abs() < 1e-9, "{gaps:?}");
        assert!((gaps[0].spread - 1.0).abs() < 1e-9, "{gaps:?}");
        // Feature 2 squeezed to half its spread around its mean: next.
        let m2 = real.iter().map(|r| r[2]).sum::<f64>() / 60.0;
        let squeezed: Vec<Vec<f64>> = moved
            .iter()
            .map(|r| {
                let mut r = r.clone();
                r[2] = m2 + 0.5 * (r[2] - m2);
                r
            })
            .collect();
        let gaps = feature_gaps(&real, &squeezed, 3);
        assert_eq!((gaps[0].feature, gaps[1].feature), (4, 2), "{gaps:?}");
        assert!(gaps[1].z.abs() < 1e-9 && (gaps[1].spread - 0.5).abs() < 1e-9);
        // A feature constant in both sets (a root held in place) is no
        // gap; constant in the real set only, its whole spread is.
        let mut flat_real = real.clone();
        let mut flat_gen = real.clone();
        for r in flat_real.iter_mut().chain(flat_gen.iter_mut()) {
            r[0] = 0.0;
        }
        let none = feature_gaps(&flat_real, &flat_gen, 6);
        let f0 = none.iter().find(|g| g.feature == 0).unwrap();
        assert_eq!((f0.z, f0.spread, f0.cost), (0.0, 1.0, 0.0));
        flat_gen[0][0] = 0.3;
        flat_gen[1][0] = -0.3;
        let g0 = feature_gaps(&flat_real, &flat_gen, 1)[0];
        assert_eq!(g0.feature, 0, "{g0:?}");
        let sd = (2.0 * 0.09 / 59.0f64).sqrt();
        assert!((g0.spread - sd).abs() < 1e-12 && (g0.cost - sd * sd).abs() < 1e-12);
        assert!((gaps[1].cost - 0.25).abs() < 1e-9);
    }

    #[test]
    fn the_first_axis_is_the_shared_factor_and_carries_its_share_of_fid() {
        use rand::{Rng, SeedableRng};
        // Features 0 and 1 share a strong factor f; feature 2 is noise.
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let mut noise = || rng.gen::<f64>() - 0.5;
        let rows: Vec<(f64, [f64; 3])> = (0..400)
            .map(|_| (4.0 * noise(), [noise(), noise(), noise()]))
            .collect();
        let make = |scale: f64| -> Vec<Vec<f64>> {
            rows.iter()
                .map(|(f, e)| vec![scale * f + 0.3 * e[0], scale * f + 0.3 * e[1], e[2]])
                .collect()
        };
        let (real, same, calm) = (make(1.0), make(1.0), make(0.5));
        let a = first_axis(&real, &same).unwrap();
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            (a.loadings[0] - h).abs() < 0.01 && (a.loadings[1] - h).abs() < 0.01,
            "{a:?}"
        );
        assert!(a.loadings[2].abs() < 0.05, "{a:?}");
        // Two standardised features almost one: the axis holds ~2 of 3.
        assert!((a.real_share - 2.0 / 3.0).abs() < 0.03, "{a:?}");
        assert!(
            a.cost < 1e-9 && a.fid_without < 1e-9 && a.shift.abs() < 1e-9,
            "{a:?}"
        );
        assert!((a.gen_var - a.real_var).abs() < 1e-9);
        // The factor halved: a quarter of the variance along the axis,
        // the FID is almost all the axis's, and little is left without it.
        let c = first_axis(&real, &calm).unwrap();
        assert!((c.gen_var / c.real_var - 0.25).abs() < 0.02, "{c:?}");
        let whole = fid(&real, &calm).unwrap();
        // (f's sample mean is not exactly 0, so halving it moves the mean
        // a little.)
        let expect = c.shift.powi(2) * c.real_var + (c.real_var.sqrt() - c.gen_var.sqrt()).powi(2);
        assert!(
            (c.cost - expect).abs() < 1e-9 && c.shift.abs() < 0.01,
            "{c:?}"
        );
        assert!(c.fid_without < 0.02 * whole, "{c:?} {whole}");
        assert!(
            (c.cost + c.fid_without - whole).abs() < 0.05 * whole,
            "{c:?} {whole}"
        );
        // The same-size yardstick takes any distance.
        let by = same_size_by(&real, &same, 50, |r, p| {
            first_axis(r, p).map(|a| a.fid_without)
        });
        assert!(by.is_some_and(|x| x >= 0.0));
        assert!(first_axis(&real[..1], &same).is_none());
    }

    #[test]
    fn beat_alignment_by_hand() {
        let (m2k, k2m) = beat_alignment(&[0, 30, 60], &[0, 33], 3.0).unwrap();
        // Music 0 → 0 (1), 30 → 33 (e^{-0.5}), 60 → 33 (e^{-40.5}).
        let want = (1.0 + (-0.5f64).exp() + (-40.5f64).exp()) / 3.0;
        assert!((m2k - want).abs() < 1e-12);
        assert!((k2m - (1.0 + (-0.5f64).exp()) / 2.0).abs() < 1e-12);
        assert!(beat_alignment(&[], &[1], 3.0).is_none());
    }

    #[test]
    fn kinetic_features_of_constant_velocity() {
        // One joint moving 1 m/s along x at 60 fps: horizontal KE 1, vertical
        // 0, acceleration 0.
        let p: Vec<Vec3> = (0..30).map(|t| [t as f64 / 60.0, 0.0, 0.0]).collect();
        let k = kinetic_features(&p, 1, 60.0);
        assert!(
            (k[0] - 1.0).abs() < 1e-9 && k[1].abs() < 1e-12 && k[2].abs() < 1e-6,
            "{k:?}"
        );
    }

    #[test]
    fn geometric_features_of_a_still_rest_pose() {
        let rest = Motion::rest_positions(&Skeleton::smpl24());
        let p: Vec<Vec3> = (0..5).flat_map(|_| rest.iter().copied()).collect();
        let g = geometric_features(&p, 24);
        assert_eq!(g.len(), GEOMETRIC_DIMS);
        // Nothing moves: every velocity feature is 0.
        for k in [0, 1, 4, 5, 9, 10, 11, 12, 13, 21, 22, 31] {
            assert_eq!(g[k], 0.0, "feature {k}");
        }
        // Standing upright: the neck–root line is vertical, not within 70–110°
        // of up; the knees are straight (180°, not within 0–110°).
        assert_eq!(g[28], 0.0);
        assert_eq!((g[19], g[20]), (0.0, 0.0));
    }

    #[test]
    fn fid_range_brackets_the_figure_and_narrows_with_more_samples() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut rows = |n: usize, shift: f64| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| (0..4).map(|_| shift + rng.gen_range(-0.5..0.5)).collect())
                .collect()
        };
        let real = rows(60, 0.0);
        let far = rows(40, 2.0);
        let many = rows(400, 2.0);
        let exact = fid(&real, &far).unwrap();
        let [lo, hi] = fid_range(&real, &far).unwrap();
        assert!(lo <= exact && exact <= hi, "{lo} {exact} {hi}");
        // The same distribution, ten times the samples: a narrower range.
        let [lo2, hi2] = fid_range(&real, &many).unwrap();
        assert!(hi2 - lo2 < hi - lo, "{lo2}–{hi2} against {lo}–{hi}");
        // Deterministic: the same samples give the same range.
        assert_eq!(fid_range(&real, &far), Some([lo, hi]));
        // One sample has no covariance to resample.
        assert_eq!(fid_range(&real, &far[..1]), None);
    }
}
