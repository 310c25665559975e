//! The real yardstick at the generated length ([`super::row::RealChained`]):
//! real *training* takes of each label played on to the generated clips'
//! length, measured against the held-out real takes as a generated clip
//! is. A corpus of short takes (Bandai's average 4 s) judges a 10 s clip
//! against takes that hold one action at full tilt for 2–4 s; this says
//! what 10 s of real motion of the label scores against them.

use super::{ClipStats, RealClip};
use crate::motion::labels::but_take;
use crate::motion::Motion;
use crate::tokenize::vocab::Vocabulary;

/// `per_label` clips of `frames` frames for each of `values` (of label
/// `kind`): clip `i` starts with the `i`-th training take of the value (in
/// the split's hash order, round again when there are fewer) and goes on
/// with the takes sharing its every label but the take number (itself
/// again when it has none, or when they run out), chained where each best
/// goes on from the last ([`Motion::chain`]) and cut to `frames`. Takes
/// that do not chain are reported through `say` and left out.
pub(super) fn chained_clips(
    vocab: &Vocabulary,
    train: &[RealClip],
    (kind, values): (&str, &[String]),
    per_label: usize,
    frames: usize,
    say: &mut dyn FnMut(String),
) -> Vec<(String, Vec<u32>)> {
    let fl = vocab.frame_len();
    let bridge = (Motion::CHAIN_BRIDGE_S * vocab.fps).round() as usize;
    let mut out = Vec::new();
    for v in values {
        let takes: Vec<&RealClip> = train
            .iter()
            .filter(|c| c.labels.get(kind) == Some(v) && c.motion.frames() > 1)
            .collect();
        if takes.is_empty() {
            continue;
        }
        for i in 0..per_label {
            let first = takes[i % takes.len()];
            let key = but_take(&first.labels);
            let group: Vec<&RealClip> = takes
                .iter()
                .copied()
                .filter(|c| but_take(&c.labels) == key)
                .collect();
            let at = group
                .iter()
                .position(|c| std::ptr::eq(*c, first))
                .unwrap_or(0);
            // Enough takes that, each entering up to half-way in, the
            // chain outlasts the clip.
            let mut chain = vec![first.motion.clone()];
            let mut have = first.motion.frames();
            let mut k = at;
            while have < 2 * frames + 2 && chain.len() < 64 {
                k = (k + 1) % group.len();
                have += group[k].motion.frames() / 2;
                chain.push(group[k].motion.clone());
            }
            let tokens = Motion::chain(&chain, bridge)
                .map_err(|e| e.to_string())
                .and_then(|m| vocab.encode_motion(&m).map_err(|e| e.to_string()));
            match tokens {
                Ok(t) if t.len() >= frames * fl => out.push((v.clone(), t[..frames * fl].to_vec())),
                Ok(t) => say(format!(
                    "real takes chained: {} runs {} frames, short of {frames}; left out",
                    first.name,
                    t.len() / fl
                )),
                Err(e) => say(format!(
                    "real takes chained from {}: {e}; left out",
                    first.name
                )),
            }
        }
    }
    out
}

/// The chained clips' measures against the held-out real ones.
pub(super) fn measure(
    chained: &[(String, ClipStats)],
    real: &[(String, ClipStats)],
) -> super::row::RealChained {
    let kin = |c: &[(String, ClipStats)]| -> Vec<Vec<f64>> {
        c.iter().map(|r| r.1.kinetic.clone()).collect()
    };
    let geo = |c: &[(String, ClipStats)]| -> Vec<Vec<f64>> {
        c.iter().map(|r| r.1.geometric.clone()).collect()
    };
    let (rk, ck) = (kin(real), kin(chained));
    let ratio = |f: fn(&ClipStats) -> f64| {
        super::mean(chained.iter().map(|r| f(&r.1))) / super::mean(real.iter().map(|r| f(&r.1)))
    };
    super::row::RealChained {
        clips: chained.len(),
        fid_k: super::fid(&rk, &ck),
        fid_g: super::fid(&geo(real), &geo(chained)),
        accel_ratio: ratio(|s| s.accel),
        jerk_ratio: ratio(|s| s.jerk),
        skate_ratio: ratio(|s| s.skate),
        diversity: super::diversity(&ck, &rk),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{Labels, Skeleton};

    /// A take of `n` frames at 20 fps walking along x at 1 m/s, the knees
    /// swinging, labelled `style` / `content` / `take`.
    fn take(name: &str, style: &str, content: &str, n: usize) -> RealClip {
        let v = Vocabulary::new(Default::default());
        let sk = Skeleton::smpl13();
        let trans = (0..n).map(|f| [f as f64 / 20.0, 0.9, 0.0]).collect();
        let mut rots = vec![[0.0; 3]; n * sk.len()];
        for f in 0..n {
            rots[f * sk.len() + 3][0] = 0.4 * (f as f64 * 0.6).sin();
        }
        let mut labels = Labels::new();
        labels.insert("style".into(), style.into());
        labels.insert("content".into(), content.into());
        labels.insert("take".into(), name.into());
        let m = Motion::new(name, 20.0, sk, trans, rots, labels.clone()).unwrap();
        RealClip {
            name: name.into(),
            labels,
            tokens: v.encode_motion(&m).unwrap(),
            motion: m,
        }
    }

    #[test]
    fn short_takes_play_on_to_the_clip_length_with_their_alike_takes() {
        let v = Vocabulary::new(Default::default());
        let fl = v.frame_len();
        let train = vec![
            take("a1", "angry", "walk", 12),
            take("a2", "angry", "walk", 15),
            take("a3", "angry", "run", 9),
            take("h1", "happy", "walk", 100),
        ];
        let values = vec!["angry".to_string(), "happy".to_string(), "sad".to_string()];
        let mut said = Vec::new();
        let clips = chained_clips(&v, &train, ("style", &values), 3, 40, &mut |l| said.push(l));
        assert!(said.is_empty(), "{said:?}");
        // Three clips of each value with training takes (none of "sad"),
        // every one 40 frames, though no angry take is half as long.
        assert_eq!(clips.len(), 6);
        assert!(clips.iter().all(|(_, t)| t.len() == 40 * fl));
        assert_eq!(clips.iter().filter(|c| c.0 == "angry").count(), 3);
        // Each starts with its own take: the first angry clip is a1's
        // frames, the second a2's, the third a3's (looped on itself, the
        // only angry run).
        for (i, src) in [0usize, 1, 2].iter().enumerate() {
            let own = &train[*src].tokens;
            assert_eq!(&clips[i].1[..fl * 5], &own[..fl * 5], "clip {i}");
        }
        // The walk goes on walking: the root's ground speed stays near
        // 1 m/s through the joins.
        for f in clips[0].1.chunks_exact(fl).skip(1) {
            let (vx, vz) = v.decode_root_velocity(f);
            assert!(((vx * vx + vz * vz).sqrt() - 1.0).abs() < 0.1, "{vx} {vz}");
        }
    }
}
