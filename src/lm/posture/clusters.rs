//! Pose clusters of a label's frames (`choreo postures --clusters`): the
//! poses a style or content is held in, each with its share, so the pull
//! can follow the one a clip is in instead of the label's one mean pose.

use super::{pulled, slot_stat, wraps, SlotStat};
use serde::{Deserialize, Serialize};

/// One pose cluster of a label: its share of the label's frames and each
/// slot's mean and spread within it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Component {
    pub weight: f64,
    pub slots: Vec<Option<SlotStat>>,
}

/// k-means (farthest-point start, 15 rounds) over the pulled slots of
/// `frames`, each slot's bin placed on the circle (cos, sin) so angles
/// compare the short way round (the root's height too: its 360 bins span
/// 2.5 m, so distances only fold back past 1.25 m apart, a spread no
/// label's heights reach);
/// each cluster's share and slot stats (the height's linear, as
/// [`slot_stat`] gives it).
pub(super) fn cluster(frames: &[&[u32]], k: usize, bins: f64, slots: usize) -> Vec<Component> {
    let w = std::f64::consts::TAU / bins;
    let ps: Vec<usize> = (0..slots).filter(|&s| pulled(s, slots)).collect();
    let feat = |f: &[u32]| -> Vec<f64> {
        ps.iter()
            .flat_map(|&s| {
                let a = f[s] as f64 * w;
                [a.cos(), a.sin()]
            })
            .collect()
    };
    let xs: Vec<Vec<f64>> = frames.iter().map(|f| feat(f)).collect();
    let d2 = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>();
    let k = k.min(xs.len()).max(1);
    let mut cs: Vec<Vec<f64>> = vec![xs[xs.len() / 2].clone()];
    while cs.len() < k {
        let far = (0..xs.len())
            .max_by(|&i, &j| {
                let di = cs.iter().map(|c| d2(&xs[i], c)).fold(f64::MAX, f64::min);
                let dj = cs.iter().map(|c| d2(&xs[j], c)).fold(f64::MAX, f64::min);
                di.total_cmp(&dj)
            })
            .unwrap();
        cs.push(xs[far].clone());
    }
    let mut assign = vec![0usize; xs.len()];
    for _ in 0..15 {
        for (i, x) in xs.iter().enumerate() {
            assign[i] = (0..cs.len())
                .min_by(|&a, &b| d2(x, &cs[a]).total_cmp(&d2(x, &cs[b])))
                .unwrap();
        }
        for (c, centre) in cs.iter_mut().enumerate() {
            let members: Vec<&Vec<f64>> = xs
                .iter()
                .zip(&assign)
                .filter(|(_, &a)| a == c)
                .map(|(x, _)| x)
                .collect();
            if members.is_empty() {
                continue;
            }
            for (j, v) in centre.iter_mut().enumerate() {
                *v = members.iter().map(|m| m[j]).sum::<f64>() / members.len() as f64;
            }
        }
    }
    (0..cs.len())
        .filter_map(|c| {
            let mine: Vec<&[u32]> = frames
                .iter()
                .zip(&assign)
                .filter(|(_, &a)| a == c)
                .map(|(f, _)| *f)
                .collect();
            (!mine.is_empty()).then(|| Component {
                weight: mine.len() as f64 / frames.len() as f64,
                slots: (0..slots)
                    .map(|s| {
                        pulled(s, slots).then(|| {
                            slot_stat(mine.iter().map(|f| f[s] as f64), bins, wraps(s, slots))
                        })
                    })
                    .collect(),
            })
        })
        .collect()
}
