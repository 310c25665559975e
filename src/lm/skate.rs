//! A price on foot skating (`sampling.skate`): among a frame's candidates
//! (`sampling.draws`), a preference for the one whose planted feet stay
//! where they are. A foot slides when its ankle lies within
//! [`PLANT_HEIGHT`] of the lowest height the clip's ankles have reached
//! (the seed's frames included) both in the frame before and in the
//! candidate, and moves over the ground between them; a candidate's cost
//! is the summed ground speed (m/s) of its sliding ankles, the root's
//! travel included (forward kinematics of the two frames, as the tokens
//! decode). A foot that lifts off costs nothing: a step is not a slide.
//! The generator adds `skate ×` that cost to each candidate's distance
//! from typical ([`super::typical`]), in nats per m/s, and keeps the
//! least.
//!
//! Sliding feet are what the eye catches first in generated motion, and
//! what `eval generate`'s skating column measures (ankles' ground speed
//! near the clip's floor). Pinning the legs afterwards (`feet: pin`)
//! bends them to the pin; the price instead chooses, while drawing, the
//! candidate whose legs already hold the foot, so what follows is drawn
//! from a planted foot.

use crate::tokenize::vocab::Vocabulary;

/// An ankle this close above the lowest height the clip's ankles have
/// reached (metres), in the frame before and in the candidate, is
/// planted: its ground movement between them costs.
pub const PLANT_HEIGHT: f64 = 0.05;

/// The clip's planted-feet tracker: the vocabulary's ankles and the lowest
/// ankle height so far.
#[derive(Clone, Debug)]
pub struct Feet {
    ankles: [usize; 2],
    floor: f64,
}

impl Feet {
    /// The tracker for a clip continuing `seed` (whole frames of value
    /// slots, no separator); None when the vocabulary's skeleton has no
    /// `Left_Ankle` and `Right_Ankle`.
    pub fn new(v: &Vocabulary, seed: &[Vec<u32>]) -> Option<Feet> {
        let sk = v.skeleton_def()?;
        let ankles = [sk.index_of("Left_Ankle")?, sk.index_of("Right_Ankle")?];
        let mut feet = Feet {
            ankles,
            floor: f64::INFINITY,
        };
        if !seed.is_empty() {
            if let Some(h) = feet.heights(v, seed) {
                feet.floor = h.into_iter().flatten().fold(f64::INFINITY, f64::min);
            }
        }
        Some(feet)
    }

    /// Each frame's two ankle positions (None when the tokens do not
    /// decode).
    fn positions(&self, v: &Vocabulary, frames: &[&[u32]]) -> Option<Vec<[[f64; 3]; 2]>> {
        let mut t = Vec::with_capacity(frames.len() * v.frame_len());
        for f in frames {
            t.extend_from_slice(f);
            t.push(v.sep());
        }
        let m = v.decode_motion(&t, "candidate").ok()?;
        let j = m.joints();
        let p = m.positions();
        Some(
            (0..frames.len())
                .map(|f| [p[f * j + self.ankles[0]], p[f * j + self.ankles[1]]])
                .collect(),
        )
    }

    fn heights(&self, v: &Vocabulary, frames: &[Vec<u32>]) -> Option<Vec<[f64; 2]>> {
        let refs: Vec<&[u32]> = frames.iter().map(|f| f.as_slice()).collect();
        let p = self.positions(v, &refs)?;
        Some(p.iter().map(|a| [a[0][1], a[1][1]]).collect())
    }

    /// Each candidate's cost after `prev`: the summed ground speed (m/s,
    /// at the vocabulary's frame rate) of the ankles low in both `prev`
    /// and the candidate. The floor first takes in `prev`'s ankles (a clip
    /// without a seed starts on its first frame's lower foot). Each pair
    /// is decoded on its own, so the root's travel into the candidate is
    /// its own velocity slots'.
    pub fn costs(&mut self, v: &Vocabulary, prev: &[u32], cands: &[&[u32]]) -> Vec<f64> {
        let fps = v.fps;
        let mut out = Vec::with_capacity(cands.len());
        for (i, c) in cands.iter().enumerate() {
            let Some(p) = self.positions(v, &[prev, c]) else {
                out.push(0.0);
                continue;
            };
            if i == 0 {
                self.floor = self.floor.min(p[0][0][1]).min(p[0][1][1]);
            }
            let mut cost = 0.0;
            for a in 0..2 {
                let (from, to) = (p[0][a], p[1][a]);
                let low = self.floor + PLANT_HEIGHT;
                if from[1] < low && to[1] < low {
                    cost += ((to[0] - from[0]).powi(2) + (to[2] - from[2]).powi(2)).sqrt() * fps;
                }
            }
            out.push(cost);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocab() -> Vocabulary {
        Vocabulary::new(Default::default())
    }

    /// A frame of value slots from a motion's tokens.
    fn frames_of(v: &Vocabulary, m: &crate::motion::Motion) -> Vec<Vec<u32>> {
        let fl = v.frame_len();
        v.encode_motion(m)
            .unwrap()
            .chunks_exact(fl)
            .map(|f| f[..fl - 1].to_vec())
            .collect()
    }

    #[test]
    fn a_planted_foot_that_slides_costs_and_one_that_stays_does_not() {
        let v = vocab();
        let sk = v.skeleton_def().unwrap();
        let nj = sk.len();
        // Standing still, then the same pose 5 cm further along x (the
        // root travels, so both feet slide), then lifted 30 cm.
        let rots = vec![[0.0; 3]; 3 * nj];
        let trans = vec![[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.05, 0.3, 0.0]];
        let m =
            crate::motion::Motion::new("t", v.fps, sk, trans, rots, Default::default()).unwrap();
        let f = frames_of(&v, &m);
        let mut feet = Feet::new(&v, &f[..1]).expect("SMPL-13 has ankles");
        // The same frame again: only the root velocity bin's rounding.
        let c = feet.costs(&v, &f[0], &[&f[0], &f[1]]);
        assert!(c[0].abs() < 0.1, "{c:?}");
        // Both ankles planted, each sliding about 5 cm in a frame (1 m/s
        // at 20 fps), within the bins' resolution.
        assert!((c[1] - 2.0 * 0.05 * v.fps).abs() < 0.3, "{c:?}");
        // A lifted foot moving is not skating.
        let c = feet.costs(&v, &f[2], &[&f[1]]);
        assert!(c[0].abs() < 1e-9, "{c:?}");
    }
}
