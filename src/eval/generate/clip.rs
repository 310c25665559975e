//! Per-clip measures of `choreo eval generate`: one clip's kinetic and
//! geometric features, smoothness, skating and judge windows
//! ([`clip_stats`]), and the diversity of a set of clips.

use super::*;

/// A SMPL-13 motion on the full SMPL-24 tree (dropped joints at rest),
/// which has the same joint positions: the 13-joint offsets fold exactly
/// the dropped joints' rest offsets.
fn lift24(m: &Motion) -> Motion {
    let n = m.frames();
    let mut rot = vec![[0.0; 3]; n * 24];
    for f in 0..n {
        for (i, &k) in SMPL13_FROM_24.iter().enumerate() {
            rot[f * 24 + k] = m.rotations[f * 13 + i];
        }
    }
    Motion::new(
        m.name.clone(),
        m.fps,
        Skeleton::smpl24(),
        m.trans.clone(),
        rot,
        m.labels.clone(),
    )
    .expect("the SMPL-24 tree takes a lifted SMPL-13 motion")
}

/// What one clip (real or generated) measures.
pub(super) struct ClipStats {
    pub(super) kinetic: Vec<f64>,
    pub(super) geometric: Vec<f64>,
    pub(super) accel: f64,
    pub(super) jerk: f64,
    pub(super) skate: f64,
    /// Mean root-relative joint speed per 1 s window (m/s).
    pub(super) window_speed: Vec<f64>,
    /// Token-statistics windows for the conditioning judge.
    pub(super) lda_windows: Vec<Vec<f64>>,
    /// Per frame: the root's tilt from the vertical (degrees), and the
    /// height of the body's lowest joint (m): a body lying down, floating
    /// or sunk into the floor shows here.
    pub(super) tilt: Vec<f64>,
    pub(super) lowest: Vec<f64>,
}

const JUDGE_FRAMES: usize = 40;

/// `in_place`: the root's ground-plane path is dropped (x and z held at
/// 0), for a corpus whose real clips dance in place (no root trajectory):
/// the generated travel then has nothing real to be compared with.
pub(super) fn clip_stats(
    vocab: &Vocabulary,
    tokens: &[u32],
    in_place: bool,
    (root_from_feet, pin_feet): (bool, bool),
) -> Result<ClipStats, String> {
    let fl = vocab.frame_len();
    let mut m = vocab
        .decode_motion(tokens, "clip")
        .map_err(|e| e.to_string())?;
    if root_from_feet {
        m = crate::motion::contact::lock_feet(&m);
    }
    if in_place {
        for t in &mut m.trans {
            (t[0], t[2]) = (0.0, 0.0);
        }
    }
    // Pinned feet: the legs change, so the judge and the tilt read the
    // pinned clip's tokens, not the drawn ones.
    let pinned;
    let tokens = if pin_feet {
        m = crate::motion::foot_pin::pin_feet(&m);
        // The joint-angle slots re-encoded; the root's slots as drawn.
        let angles = 3 * vocab.joints.len();
        let enc = vocab.encode_motion(&m).map_err(|e| e.to_string())?;
        let mut t = tokens.to_vec();
        for (dst, src) in t.chunks_exact_mut(fl).zip(enc.chunks_exact(fl)) {
            dst[..angles].copy_from_slice(&src[..angles]);
        }
        pinned = t;
        &pinned[..]
    } else {
        tokens
    };
    let m24 = lift24(&m);
    let p = m24.positions();
    let j = 24;
    let n = p.len() / j;
    let fps = m.fps;
    let rel = |f: usize, k: usize| -> Vec3 {
        let a = p[f * j + k];
        let r = p[f * j];
        [a[0] - r[0], a[1] - r[1], a[2] - r[2]]
    };
    let body: Vec<usize> = SMPL13_FROM_24.to_vec();
    let norm = |v: Vec3| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let (mut acc, mut jerk, mut na, mut nj) = (0.0, 0.0, 0usize, 0usize);
    for f in 1..n.saturating_sub(1) {
        for &k in &body[1..] {
            let (a, b, c) = (rel(f - 1, k), rel(f, k), rel(f + 1, k));
            acc += norm([
                c[0] - 2.0 * b[0] + a[0],
                c[1] - 2.0 * b[1] + a[1],
                c[2] - 2.0 * b[2] + a[2],
            ]) * fps
                * fps;
            na += 1;
            if f + 2 < n {
                let d = rel(f + 2, k);
                jerk += norm([
                    d[0] - 3.0 * c[0] + 3.0 * b[0] - a[0],
                    d[1] - 3.0 * c[1] + 3.0 * b[1] - a[1],
                    d[2] - 3.0 * c[2] + 3.0 * b[2] - a[2],
                ]) * fps
                    * fps
                    * fps;
                nj += 1;
            }
        }
    }
    // Foot skating: ankles' horizontal speed while near the clip's floor.
    let (mut skate, mut ns) = (0.0, 0usize);
    for &ankle in &[7usize, 8] {
        let floor = (0..n)
            .map(|f| p[f * j + ankle][1])
            .fold(f64::INFINITY, f64::min);
        for f in 1..n {
            let (a, b) = (p[(f - 1) * j + ankle], p[f * j + ankle]);
            if b[1] < floor + 0.03 {
                skate += ((b[0] - a[0]).powi(2) + (b[2] - a[2]).powi(2)).sqrt() * fps;
                ns += 1;
            }
        }
    }
    let win = fps.round().max(2.0) as usize;
    let mut window_speed = Vec::new();
    let mut st = 0;
    while st + win <= n {
        let (mut s, mut c) = (0.0, 0usize);
        for f in st + 1..st + win {
            for &k in &body[1..] {
                let (a, b) = (rel(f - 1, k), rel(f, k));
                s += norm([b[0] - a[0], b[1] - a[1], b[2] - a[2]]) * fps;
                c += 1;
            }
        }
        window_speed.push(s / c.max(1) as f64);
        st += win;
    }
    let frames = tokens.len() / fl;
    let mut lda_windows = Vec::new();
    let mut st = 0;
    while st + JUDGE_FRAMES <= frames {
        lda_windows.push(window_features(
            &tokens[st * fl..(st + JUDGE_FRAMES) * fl],
            fl,
            vocab.bins,
        ));
        st += JUDGE_FRAMES;
    }
    Ok(ClipStats {
        kinetic: kinetic_features(&p, j, fps),
        geometric: geometric_features(&p, j),
        accel: acc / na.max(1) as f64,
        jerk: jerk / nj.max(1) as f64,
        skate: skate / ns.max(1) as f64,
        window_speed,
        lda_windows,
        tilt: {
            let angles = vocab.angle_bins();
            tokens
                .chunks_exact(fl)
                .map(|f| crate::lm::posture::frame_tilt(f, &angles))
                .collect()
        },
        lowest: (0..n)
            .map(|f| {
                (0..j)
                    .map(|k| p[f * j + k][1])
                    .fold(f64::INFINITY, f64::min)
            })
            .collect(),
    })
}

/// Mean pairwise Euclidean distance of feature rows standardised by the
/// reference set's mean and spread.
pub(super) fn diversity(rows: &[Vec<f64>], reference: &[Vec<f64>]) -> f64 {
    let d = match reference.first() {
        Some(r) => r.len(),
        None => return 0.0,
    };
    let n = reference.len() as f64;
    let mean: Vec<f64> = (0..d)
        .map(|k| reference.iter().map(|r| r[k]).sum::<f64>() / n)
        .collect();
    let sd: Vec<f64> = (0..d)
        .map(|k| {
            let v = reference
                .iter()
                .map(|r| (r[k] - mean[k]).powi(2))
                .sum::<f64>()
                / n;
            if v > 1e-24 {
                v.sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let z: Vec<Vec<f64>> = rows
        .iter()
        .map(|r| (0..d).map(|k| (r[k] - mean[k]) / sd[k]).collect())
        .collect();
    let (mut s, mut c) = (0.0, 0usize);
    for i in 0..z.len() {
        for k in i + 1..z.len() {
            s += z[i]
                .iter()
                .zip(&z[k])
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            c += 1;
        }
    }
    s / c.max(1) as f64
}
