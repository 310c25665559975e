//! Motion matching as a pull (`sampling.matching`). Each frame, the real
//! training frame of the asked-for labels nearest the clip's last frame
//! (its pose and its change from the frame before, joint angles and the
//! root's height) is found among the model folder's exemplar spans
//! ([`super::exemplars`]: training takes only), and every joint slot is
//! pulled toward a target, `−w d(b, target)² / (2σ²)` on every bin b,
//! beside the model's own distribution. The target is the matched frame's
//! successor moved half-way toward the clip's own pose: half "go where the
//! real take goes", half "move as the real take moves from where the clip
//! is".
//!
//! The label postures ([`super::posture`]) pull toward where a label holds
//! a joint, a still pose, and damp every swing; this pulls toward where a
//! real take of the label goes next. With `matching` on, the postures hold
//! only the body's tilt (the root's rotation, which matching leaves alone:
//! a take's heading is its own) and the joints follow the takes
//! (docs/RESULTS.md, "Session 43").

use super::exemplars::Exemplars;
use super::frame::{short_step, slot_wraps as wraps};
use crate::motion::Labels;

/// The change term's weight in the match distance: a joint's change a
/// frame is a few bins where poses differ by tens, so a bin of change
/// counts this many times a bin of pose (squared).
const CHANGE_WEIGHT: f64 = 4.0;

/// The target's spread (bins).
pub const SPREAD: f64 = 4.0;

/// How far the target sits from the clip's own pose moved by the matched
/// take's change (0) toward the matched take's next pose (1).
const TOWARD_TAKE: f64 = 0.5;

/// The real frames a labelled request follows: spans of frames (slot
/// tokens, separator dropped), each at least 3 frames long.
#[derive(Clone, Debug)]
pub struct Library {
    slots: usize,
    bins: usize,
    spans: Vec<Vec<Vec<u32>>>,
}

/// Whether slot `s` of `slots` is matched and pulled: the slots the label
/// postures pull, a joint angle (not the root's rotation, whose heading
/// any take may choose) or the root's height; not the root's ground
/// velocity (world-frame travel).
pub fn followed(s: usize, slots: usize) -> bool {
    super::posture::pulled(s, slots)
}

impl Library {
    /// The spans whose labels hold every one of `labels` (None without
    /// labels or without such a span of 3 frames or more).
    pub fn for_labels(
        ex: &Exemplars,
        labels: &Labels,
        slots: usize,
        bins: usize,
    ) -> Option<Library> {
        let spans = ex
            .spans()
            .filter(|(it, _)| labels.iter().all(|(k, v)| it.labels.get(k) == Some(v)))
            .map(|(_, toks)| {
                toks.chunks_exact(slots + 1)
                    .map(|f| f[..slots].to_vec())
                    .collect()
            })
            .collect();
        Library::new(spans, slots, bins).filter(|_| !labels.is_empty())
    }

    /// A library of `spans` (frames of `slots` value tokens); spans under 3
    /// frames are dropped; None if none is left.
    pub fn new(spans: Vec<Vec<Vec<u32>>>, slots: usize, bins: usize) -> Option<Library> {
        let spans: Vec<Vec<Vec<u32>>> = spans.into_iter().filter(|s| s.len() >= 3).collect();
        (!spans.is_empty()).then_some(Library { slots, bins, spans })
    }

    /// `a − b` in bins, the shorter way round for an angle.
    fn diff(&self, s: usize, a: u32, b: u32) -> f64 {
        if wraps(s, self.slots) {
            short_step(a, b, self.bins) as f64
        } else {
            a as f64 - b as f64
        }
    }

    /// The library frame nearest `p1` (pose, and with `p2` the change from
    /// `p2` to `p1` against the library frame's own change): (span, frame),
    /// never a span's last frame (it has no successor).
    pub fn nearest(&self, p1: &[u32], p2: Option<&[u32]>) -> (usize, usize) {
        let mut best = (f64::INFINITY, 0, 1);
        for (si, span) in self.spans.iter().enumerate() {
            for j in 1..span.len() - 1 {
                let (x, xp) = (&span[j], &span[j - 1]);
                let mut cost = 0.0;
                for s in (0..self.slots).filter(|&s| followed(s, self.slots)) {
                    let d = self.diff(s, p1[s], x[s]);
                    cost += d * d;
                    if let Some(p2) = p2 {
                        let v = self.diff(s, p1[s], p2[s]) - self.diff(s, x[s], xp[s]);
                        cost += CHANGE_WEIGHT * v * v;
                    }
                    if cost >= best.0 {
                        break;
                    }
                }
                if cost < best.0 {
                    best = (cost, si, j);
                }
            }
        }
        (best.1, best.2)
    }

    /// The target for the frame after `p1` (see the module's text): per
    /// slot, the matched frame's successor y moved toward `p1` by half of
    /// `p1 − x` (x the matched frame); slots not followed keep y's value
    /// (they are not pulled).
    pub fn target(&self, p1: &[u32], p2: Option<&[u32]>) -> Vec<u32> {
        let (si, j) = self.nearest(p1, p2);
        let (x, y) = (&self.spans[si][j], &self.spans[si][j + 1]);
        let n = self.bins as f64;
        (0..self.slots)
            .map(|s| {
                let v = y[s] as f64 + (1.0 - TOWARD_TAKE) * self.diff(s, p1[s], x[s]);
                if wraps(s, self.slots) {
                    v.round().rem_euclid(n) as u32
                } else {
                    v.round().clamp(0.0, n - 1.0) as u32
                }
            })
            .collect()
    }

    /// Slot `s`'s logit offsets toward `target` times `weight` (None for a
    /// slot not followed).
    pub fn offsets(&self, target: &[u32], s: usize, weight: f64) -> Option<Vec<f32>> {
        followed(s, self.slots).then(|| {
            let k = weight / (2.0 * SPREAD * SPREAD);
            (0..self.bins)
                .map(|b| {
                    let d = self.diff(s, b as u32, target[s]);
                    (-k * d * d) as f32
                })
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // 8 slots: 0–2 the root's rotation, 3–4 joints, 5–6 the root's ground
    // velocity, 7 its height; 360 bins.
    fn frame(j: [u32; 2], h: u32) -> Vec<u32> {
        vec![0, 0, 0, j[0], j[1], 180, 180, h]
    }

    #[test]
    fn only_joints_and_the_height_are_followed() {
        let f: Vec<bool> = (0..8).map(|s| followed(s, 8)).collect();
        assert_eq!(f, [false, false, false, true, true, false, false, true]);
    }

    #[test]
    fn the_nearest_frame_weighs_the_change_and_the_target_goes_half_way() {
        // Two takes through the same pose (joint 3 at 100), one rising 10
        // bins a frame, one still.
        let rising: Vec<Vec<u32>> = (0..5).map(|i| frame([80 + 10 * i, 50], 100)).collect();
        let still: Vec<Vec<u32>> = (0..5).map(|_| frame([100, 50], 100)).collect();
        let lib = Library::new(vec![still, rising], 8, 360).unwrap();
        assert_eq!(lib.spans.iter().map(|s| s.len()).sum::<usize>(), 10);
        // A clip at 104 that rose 10 bins in its last frame matches the
        // rising take's 100 (not the still one, nearer in pose alone) ...
        let (p2, p1) = (frame([94, 50], 100), frame([104, 50], 100));
        assert_eq!(lib.nearest(&p1, Some(&p2)), (1, 2));
        // ... and its target is 110 + (104 − 100) / 2 = 112.
        assert_eq!(lib.target(&p1, Some(&p2))[3], 112);
        // Without the change the still take is as near (its middle frame
        // is found first) and the target stays where the clip is: 100 + 2.
        let (si, _) = lib.nearest(&p1, None);
        assert_eq!(si, 0);
        assert_eq!(lib.target(&p1, None)[3], 102);
    }

    #[test]
    fn angles_match_and_pull_the_shorter_way_round() {
        let take: Vec<Vec<u32>> = (0..4)
            .map(|i| frame([356 + 2 * i, 50], 100))
            .map(|mut f| {
                f[3] %= 360;
                f
            })
            .collect();
        let lib = Library::new(vec![take], 8, 360).unwrap();
        // 358 → 0 → 2: a clip at 1 having come from 359 is at frame 1 (358)
        // or 2 (0); either way the target is past 0, not 180 bins off.
        let t = lib.target(&frame([1, 50], 100), Some(&frame([359, 50], 100)));
        assert!(t[3] <= 4, "target {}", t[3]);
        let off = lib.offsets(&t, 3, 1.0).unwrap();
        let best = (0..360).max_by(|&a, &b| off[a].total_cmp(&off[b])).unwrap();
        assert_eq!(best as u32, t[3]);
        assert!(off[359] > off[180]);
        assert!(lib.offsets(&t, 5, 1.0).is_none());
        // Too short a span is no library.
        assert!(Library::new(vec![vec![frame([0, 0], 0); 2]], 8, 360).is_none());
    }
}
