//! Motion matching as a pull (`sampling.matching`). Each frame, the real
//! training frame of the asked-for labels nearest the clip's last frame
//! (its pose and its change from the frame before, joint angles and the
//! root's height) is found among the model folder's exemplar spans
//! ([`super::exemplars`]: training takes only), and every joint slot is
//! pulled toward a target, `−w d(b, target)² / (2σ²)` on every bin b,
//! beside the model's own distribution. The target is half-way between
//! the matched frame's successor and the clip's own pose moved as the take
//! moves: half "go where the real take goes", half "move as the real take
//! moves from where the clip is". Joints are matched and moved as
//! rotations ([`Library`]). The root's ground velocity follows the matched
//! take's too, in the body's own heading ([`Library::travelling`]): the
//! legs and the travel come from the same real frames, so the feet slide
//! less and a clip keeps the take's pace (docs/RESULTS.md, "Session 45").
//!
//! The label postures ([`super::posture`]) pull toward where a label holds
//! a joint, a still pose, and damp every swing; this pulls toward where a
//! real take of the label goes next. With `matching` on, the postures hold
//! only the body's tilt (the root's rotation, which matching leaves alone:
//! a take's heading is its own) and the joints follow the takes
//! (docs/RESULTS.md, "Session 43" and "Session 44").

use super::exemplars::Exemplars;
use super::frame::{short_step, slot_wraps as wraps};
use crate::motion::rotation::{
    axis_angle_to_quat, geodesic_quat, quat_conj, quat_mul, quat_to_axis_angle, slerp, Quat,
};
use crate::motion::Labels;
use crate::tokenize::vocab::{heading_of, turn};
use crate::tokenize::UniformBins;

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
/// tokens, separator dropped), each at least 3 frames long, with each
/// frame's followed joints as rotations.
///
/// Joints are compared and moved as rotations, not as their three
/// axis-angle slots one by one: near a half turn an axis-angle vector
/// flips (every component changes sign) while the joint barely moves, and
/// the Bandai takes hold some joints there most of the time (the right
/// hip: 69 % of frames within 20° of the flip). Slot by slot, a take on
/// the other side of the flip looked far away, and a target mixed from
/// both sides was a pose neither had: those joints shook (their jerk
/// 1.3–2.1× the default's; docs/RESULTS.md, "Session 44").
#[derive(Clone, Debug)]
pub struct Library {
    slots: usize,
    bins: usize,
    angles: UniformBins,
    spans: Vec<Vec<Vec<u32>>>,
    /// Per span, per frame: the followed joints' rotations.
    poses: Vec<Vec<Vec<Quat>>>,
    /// Per span, per frame after the first: each followed joint's turn
    /// from the frame before (x_prev⁻¹ · x).
    turns: Vec<Vec<Vec<Quat>>>,
    /// The root's travel, where the library knows the vocabulary's
    /// velocity bins ([`Library::travelling`]).
    travel: Option<Travel>,
}

/// The root's ground velocity as the takes travel: each library frame's
/// pelvis heading and its velocity in that heading (sideways, forward),
/// so that a take walking north can lead a clip facing east.
#[derive(Clone, Debug)]
struct Travel {
    bins: UniformBins,
    /// Whether the slots already hold the velocity in the heading
    /// (`root_velocity: heading`); else in the scene's axes.
    heading_slots: bool,
    /// The pull's weight as a share of the joints' (`sampling.travel`).
    weight: f64,
    /// Per span, per frame: (heading, velocity in the heading).
    local: Vec<Vec<(f64, (f64, f64))>>,
}

/// The root's travel pull's spread (velocity bins; 0.18 m/s in the
/// bundled vocabulary's); its weight is `sampling.travel`.
const TRAVEL_SPREAD: f64 = 8.0;

/// Whether exemplar `it` carries every one of `labels`.
fn carries(it: &super::exemplars::Exemplar, labels: &Labels) -> bool {
    labels.iter().all(|(k, v)| it.labels.get(k) == Some(v))
}

/// Each joint's turn from `from` to `to`.
fn turns(from: &[Quat], to: &[Quat]) -> Vec<Quat> {
    from.iter()
        .zip(to)
        .map(|(&a, &b)| quat_mul(quat_conj(a), b))
        .collect()
}

/// Whether slot `s` of `slots` is matched and pulled: the slots the label
/// postures pull, a joint angle (not the root's rotation, whose heading
/// any take may choose) or the root's height; not the root's ground
/// velocity, which a take carries in its own heading and which follows
/// through [`Library::travelling`] instead.
pub fn followed(s: usize, slots: usize) -> bool {
    super::posture::pulled(s, slots)
}

/// The angle between two rotations, in bins of `width` radians.
fn apart(a: Quat, b: Quat, width: f64) -> f64 {
    geodesic_quat(a, b) / width
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
            .filter(|(it, _)| carries(it, labels))
            .map(|(_, toks)| {
                toks.chunks_exact(slots + 1)
                    .map(|f| f[..slots].to_vec())
                    .collect()
            })
            .collect();
        Library::new(spans, slots, bins).filter(|_| !labels.is_empty())
    }

    /// What `sampling.matching` follows in a request for `labels` on
    /// `session`: its exemplar spans carrying every one of them, the root's
    /// travel followed with weight `travel` (`sampling.travel`; 0 = not
    /// followed) where the vocabulary has velocity slots; a 400 naming the
    /// field without labels, without exemplars or without such a span.
    pub fn for_session(
        session: &super::frame_runtime::FrameSession,
        labels: &Labels,
        travel: f64,
    ) -> Result<Library, super::LmError> {
        let bad = |why: &str| super::LmError::invalid("request", "sampling.matching", why);
        if labels.is_empty() {
            return Err(bad(
                "follows the real takes of the asked-for labels, and the request asks for none",
            ));
        }
        let ex = session.exemplars.as_ref().ok_or_else(|| {
            bad("this model has no exemplars.json to follow (choreo exemplars writes one)")
        })?;
        let c = session.config();
        let v = &session.manifest.vocabulary;
        let lib = Library::for_labels(ex, labels, c.slots, c.bins).ok_or_else(|| {
            bad("no exemplar span of this model carries every asked-for label (choreo exemplars writes them)")
        })?;
        Ok(if v.frame_len() == c.slots + 1 && travel > 0.0 {
            lib.travelling(
                v.velocity_bins(),
                v.root_velocity == crate::tokenize::vocab::RootVelocity::Heading,
                travel,
            )
        } else {
            lib
        })
    }

    /// Whether [`Self::for_labels`] finds a span (without building the
    /// library).
    pub fn available(ex: &Exemplars, labels: &Labels, slots: usize) -> bool {
        !labels.is_empty()
            && ex
                .spans()
                .any(|(it, toks)| toks.len() >= 3 * (slots + 1) && carries(it, labels))
    }

    /// A library of `spans` (frames of `slots` value tokens); spans under 3
    /// frames are dropped; None if none is left.
    pub fn new(spans: Vec<Vec<Vec<u32>>>, slots: usize, bins: usize) -> Option<Library> {
        let spans: Vec<Vec<Vec<u32>>> = spans.into_iter().filter(|s| s.len() >= 3).collect();
        let mut lib = Library {
            slots,
            bins,
            angles: UniformBins::angles(bins),
            spans: Vec::new(),
            poses: Vec::new(),
            turns: Vec::new(),
            travel: None,
        };
        lib.poses = spans
            .iter()
            .map(|sp| sp.iter().map(|f| lib.pose(f)).collect::<Vec<_>>())
            .collect();
        lib.turns = lib
            .poses
            .iter()
            .map(|ps| ps.windows(2).map(|w| turns(&w[0], &w[1])).collect())
            .collect();
        lib.spans = spans;
        (!lib.spans.is_empty()).then_some(lib)
    }

    /// The library with the root's ground velocity followed too, pulled
    /// with `weight` as a share of the joints' pull: `bins`, the velocity
    /// slots' bins, and whether they hold it in the pelvis's heading (else
    /// in the scene's axes). The velocity slots are the two before the
    /// height.
    pub fn travelling(mut self, bins: UniformBins, heading_slots: bool, weight: f64) -> Library {
        let local = self
            .spans
            .iter()
            .map(|sp| {
                sp.iter()
                    .map(|f| self.local_velocity(&bins, heading_slots, f))
                    .collect()
            })
            .collect();
        self.travel = Some(Travel {
            bins,
            heading_slots,
            weight,
            local,
        });
        self
    }

    /// A frame's pelvis heading and its root velocity in that heading.
    fn local_velocity(
        &self,
        bins: &UniformBins,
        heading_slots: bool,
        f: &[u32],
    ) -> (f64, (f64, f64)) {
        let h = heading_of([0, 1, 2].map(|i| self.angles.decode(f[i])));
        let vs = self.slots - 3;
        let v = (bins.decode(f[vs]), bins.decode(f[vs + 1]));
        (h, if heading_slots { v } else { turn(v, -h) })
    }

    /// The followed joints (every joint but the root): those whose three
    /// slots are angles.
    fn joints(&self) -> std::ops::Range<usize> {
        1..(0..self.slots).filter(|&s| wraps(s, self.slots)).count() / 3
    }

    /// A frame's followed joints as rotations.
    fn pose(&self, f: &[u32]) -> Vec<Quat> {
        self.joints()
            .map(|j| axis_angle_to_quat([0, 1, 2].map(|i| self.angles.decode(f[3 * j + i]))))
            .collect()
    }

    /// `a − b` in bins of a slot that is not an angle (the height).
    fn diff(&self, a: u32, b: u32) -> f64 {
        a as f64 - b as f64
    }

    /// The library frame nearest `p1` (pose, and with `p2` the change from
    /// `p2` to `p1` against the library frame's own change; joints by the
    /// angle between rotations, the height by bins): (span, frame), never
    /// a span's last frame (it has no successor).
    pub fn nearest(&self, p1: &[u32], p2: Option<&[u32]>) -> (usize, usize) {
        self.nearest_pose(p1, &self.pose(p1), p2)
    }

    /// [`Self::nearest`] with `p1`'s rotations `q1` already worked out.
    fn nearest_pose(&self, p1: &[u32], q1: &[Quat], p2: Option<&[u32]>) -> (usize, usize) {
        let h = self.slots - 1;
        let w = self.angles.width();
        // The clip's last turn, each joint's rotation from p2 to p1.
        let c1: Option<Vec<Quat>> = p2.map(|p2| turns(&self.pose(p2), q1));
        let mut best = (f64::INFINITY, 0, 1);
        for (si, (span, poses)) in self.spans.iter().zip(&self.poses).enumerate() {
            for j in 1..span.len() - 1 {
                let dh = self.diff(p1[h], span[j][h]);
                let mut cost = dh * dh;
                if let Some(p2) = p2 {
                    let v = self.diff(p1[h], p2[h]) - self.diff(span[j][h], span[j - 1][h]);
                    cost += CHANGE_WEIGHT * v * v;
                }
                for (k, (&x, &turn)) in poses[j].iter().zip(&self.turns[si][j - 1]).enumerate() {
                    let d = apart(q1[k], x, w);
                    cost += d * d;
                    if let Some(c1) = &c1 {
                        let v = apart(c1[k], turn, w);
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
    /// joint, the rotation part-way (`TOWARD_TAKE`) from p1 turned by the
    /// matched take's change (x to its successor y) to y itself, written
    /// as the one of its axis-angle forms nearest p1's slots; the height,
    /// y's moved toward p1 by half of `p1 − x`; slots not followed keep
    /// y's value (they are not pulled).
    pub fn target(&self, p1: &[u32], p2: Option<&[u32]>) -> Vec<u32> {
        let q1 = self.pose(p1);
        let (si, j) = self.nearest_pose(p1, &q1, p2);
        let y = &self.poses[si][j + 1];
        let mut t = self.spans[si][j + 1].clone();
        for (k, jt) in self.joints().enumerate() {
            // x⁻¹ · y is the take's turn into its next frame.
            let moved = quat_mul(q1[k], self.turns[si][j][k]);
            let aa = quat_to_axis_angle(slerp(moved, y[k], TOWARD_TAKE));
            let slots = &mut t[3 * jt..3 * jt + 3];
            slots.copy_from_slice(&self.nearest_form(aa, &p1[3 * jt..3 * jt + 3]));
        }
        let h = self.slots - 1;
        let (hx, hy) = (self.spans[si][j][h] as f64, self.spans[si][j + 1][h] as f64);
        let v = hy + (1.0 - TOWARD_TAKE) * (p1[h] as f64 - hx);
        t[h] = v.round().clamp(0.0, self.bins as f64 - 1.0) as u32;
        if let Some(tr) = &self.travel {
            // The take's velocity in its heading, half moved from the
            // clip's own (as the joints), then turned into the heading the
            // clip will have: its own turned as the take turns.
            let (hx, lx) = tr.local[si][j];
            let (hy, ly) = tr.local[si][j + 1];
            let (h1, l1) = self.local_velocity(&tr.bins, tr.heading_slots, p1);
            let k = 1.0 - TOWARD_TAKE;
            let lt = (ly.0 + k * (l1.0 - lx.0), ly.1 + k * (l1.1 - lx.1));
            let v = if tr.heading_slots {
                lt
            } else {
                turn(lt, h1 + (hy - hx))
            };
            let vs = self.slots - 3;
            t[vs] = tr.bins.encode(v.0);
            t[vs + 1] = tr.bins.encode(v.1);
        }
        t
    }

    /// The bins of rotation `aa` (angle in [0, π]) nearest `near`'s: its
    /// own form, or where every component is in range its twin about the
    /// opposite axis (angle 2π − θ), the same rotation.
    fn nearest_form(&self, aa: [f64; 3], near: &[u32]) -> [u32; 3] {
        let code = |v: [f64; 3]| v.map(|c| self.angles.encode(c));
        let dist = |b: &[u32; 3]| -> i64 {
            b.iter()
                .zip(near)
                .map(|(&a, &n)| short_step(a, n, self.bins).pow(2))
                .sum()
        };
        let own = code(aa);
        let th = (aa[0] * aa[0] + aa[1] * aa[1] + aa[2] * aa[2]).sqrt();
        if th < 1e-9 {
            return own;
        }
        let twin = aa.map(|c| c * (1.0 - 2.0 * std::f64::consts::PI / th));
        if twin.iter().all(|c| c.abs() < std::f64::consts::PI) && dist(&code(twin)) < dist(&own) {
            code(twin)
        } else {
            own
        }
    }

    /// Slot `s`'s logit offsets toward `target` times `weight` (None for a
    /// slot not followed).
    pub fn offsets(&self, target: &[u32], s: usize, weight: f64) -> Option<Vec<f32>> {
        if let Some(tr) = self
            .travel
            .as_ref()
            .filter(|_| s + 3 == self.slots || s + 2 == self.slots)
        {
            let k = weight * tr.weight / (2.0 * TRAVEL_SPREAD * TRAVEL_SPREAD);
            return Some(
                (0..self.bins)
                    .map(|b| {
                        let d = self.diff(b as u32, target[s]);
                        (-k * d * d) as f32
                    })
                    .collect(),
            );
        }
        followed(s, self.slots).then(|| {
            let k = weight / (2.0 * SPREAD * SPREAD);
            (0..self.bins)
                .map(|b| {
                    let d = if wraps(s, self.slots) {
                        short_step(b as u32, target[s], self.bins) as f64
                    } else {
                        self.diff(b as u32, target[s])
                    };
                    (-k * d * d) as f32
                })
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // 9 slots: 0–2 the root's rotation, 3–5 a joint, 6–7 the root's ground
    // velocity, 8 its height; 360 bins (bin b is (b − 179.5)°).
    fn frame(j: [u32; 3], h: u32) -> Vec<u32> {
        vec![180, 180, 180, j[0], j[1], j[2], 180, 180, h]
    }

    #[test]
    fn only_joints_and_the_height_are_followed() {
        let f: Vec<bool> = (0..9).map(|s| followed(s, 9)).collect();
        assert_eq!(
            f,
            [false, false, false, true, true, true, false, false, true]
        );
    }

    #[test]
    fn the_nearest_frame_weighs_the_change_and_the_target_goes_half_way() {
        // Two takes through the same pose (the joint turned ~100° about x),
        // one turning 10° more a frame, one still.
        let rising: Vec<Vec<u32>> = (0..5)
            .map(|i| frame([260 + 10 * i, 180, 180], 100))
            .collect();
        let still: Vec<Vec<u32>> = (0..5).map(|_| frame([280, 180, 180], 100)).collect();
        let lib = Library::new(vec![still, rising], 9, 360).unwrap();
        assert_eq!(lib.spans.iter().map(|s| s.len()).sum::<usize>(), 10);
        // A clip 4° past that pose that turned 10° in its last frame
        // matches the rising take's 280 (not the still one, nearer in pose
        // alone) ...
        let (p2, p1) = (frame([274, 180, 180], 100), frame([284, 180, 180], 100));
        assert_eq!(lib.nearest(&p1, Some(&p2)), (1, 2));
        // ... and its target is 290 + (284 − 280) / 2 = 292 (a bin either
        // way: the slots are bin centres).
        let t = lib.target(&p1, Some(&p2));
        assert!((291..=293).contains(&t[3]), "target {t:?}");
        assert!(t[4].abs_diff(180) <= 1 && t[5].abs_diff(180) <= 1, "{t:?}");
        // Without the change the still take is as near (its middle frame
        // is found first) and the target stays where the clip is: 280 + 2.
        let (si, _) = lib.nearest(&p1, None);
        assert_eq!(si, 0);
        assert!((281..=283).contains(&lib.target(&p1, None)[3]));
    }

    #[test]
    fn angles_match_and_pull_the_shorter_way_round() {
        // Through the half turn about x: 176.5°, 178.5°, −179.5°, −177.5°.
        let take: Vec<Vec<u32>> = (0..4)
            .map(|i| frame([(356 + 2 * i) % 360, 180, 180], 100))
            .collect();
        let lib = Library::new(vec![take], 9, 360).unwrap();
        // 358 → 0 → 2: a clip at 1 having come from 359 is at frame 1 (358)
        // or 2 (0); either way the target is past 0, not 180 bins off.
        let t = lib.target(
            &frame([1, 180, 180], 100),
            Some(&frame([359, 180, 180], 100)),
        );
        assert!(t[3] <= 4, "target {}", t[3]);
        let off = lib.offsets(&t, 3, 1.0).unwrap();
        let best = (0..360).max_by(|&a, &b| off[a].total_cmp(&off[b])).unwrap();
        assert_eq!(best as u32, t[3]);
        assert!(off[359] > off[180]);
        assert!(lib.offsets(&t, 6, 1.0).is_none());
        // Too short a span is no library.
        assert!(Library::new(vec![vec![frame([0, 0, 0], 0); 2]], 9, 360).is_none());
    }

    #[test]
    fn a_joint_near_the_half_turn_matches_its_twin_form() {
        // 170° about (1, 1, 0)/√2, and the same rotation written the other
        // way round (190° about the opposite axis): far apart slot by slot.
        let bins = UniformBins::angles(360);
        let th = 170f64.to_radians();
        let c = th / 2f64.sqrt();
        let own = [c, c, 0.0].map(|v| bins.encode(v));
        let k = 1.0 - 2.0 * std::f64::consts::PI / th;
        let twin = [c * k, c * k, 0.0].map(|v| bins.encode(v));
        assert!(short_step(own[0], twin[0], 360).abs() > 90);
        // One take holds the pose in the twin form; another holds a pose
        // 30° away about z, nearer the clip's slots.
        let held: Vec<Vec<u32>> = vec![frame(twin, 100); 4];
        let off = frame([own[0], own[1], (own[2] + 30) % 360], 100);
        let other: Vec<Vec<u32>> = vec![off; 4];
        let lib = Library::new(vec![other, held], 9, 360).unwrap();
        // A still clip in the own form matches the held take, and its
        // target is written in the clip's form, where it already is.
        let p = frame(own, 100);
        assert_eq!(lib.nearest(&p, Some(&p)).0, 1);
        let t = lib.target(&p, Some(&p));
        for i in 0..3 {
            assert!(
                short_step(t[3 + i], own[i], 360).abs() <= 1,
                "{t:?} vs {own:?}"
            );
        }
    }

    #[test]
    fn the_root_travels_as_the_take_does_in_the_clips_heading() {
        // A take facing +z (no pelvis turn) walking forward at 1 m/s; a
        // clip turned a quarter about y (facing +x) walking forward too.
        let vb = UniformBins {
            bins: 360,
            lo: -4.0,
            hi: 4.0,
        };
        let walk = |pelvis: [u32; 3], v: (f64, f64)| {
            let mut f = frame([200, 180, 180], 100);
            f[..3].copy_from_slice(&pelvis);
            f[6] = vb.encode(v.0);
            f[7] = vb.encode(v.1);
            f
        };
        let take = vec![walk([180, 180, 180], (0.0, 1.0)); 4];
        let plain = Library::new(vec![take.clone()], 9, 360).unwrap();
        let lib = Library::new(vec![take], 9, 360)
            .unwrap()
            .travelling(vb.clone(), false, 1.0);
        let quarter = UniformBins::angles(360).encode(std::f64::consts::FRAC_PI_2);
        let p = walk([180, quarter, 180], (1.0, 0.0));
        // Without travel the velocity slots are not followed.
        assert!(plain.offsets(&plain.target(&p, Some(&p)), 6, 1.0).is_none());
        // With it the target walks along +x at the take's speed ...
        let t = lib.target(&p, Some(&p));
        assert!(t[6].abs_diff(vb.encode(1.0)) <= 1, "{t:?}");
        assert!(t[7].abs_diff(vb.encode(0.0)) <= 1, "{t:?}");
        let off = lib.offsets(&t, 7, 1.0).unwrap();
        let best = (0..360).max_by(|&a, &b| off[a].total_cmp(&off[b])).unwrap();
        assert_eq!(best as u32, t[7]);
        // `sampling.travel` scales the velocity slots' pull, and only theirs.
        let half = Library::new(vec![vec![walk([180, 180, 180], (0.0, 1.0)); 4]], 9, 360)
            .unwrap()
            .travelling(vb.clone(), false, 0.5);
        let off_half = half.offsets(&t, 7, 1.0).unwrap();
        for (h, w) in off_half.iter().zip(&off) {
            assert!((h - 0.5 * w).abs() <= 1e-4 * w.abs().max(1.0), "{h} vs {w}");
        }
        assert_eq!(half.offsets(&t, 3, 1.0), lib.offsets(&t, 3, 1.0));
        // ... and a standing clip is led half-way to the take's pace.
        let still = walk([180, quarter, 180], (0.0, 0.0));
        let t = lib.target(&still, Some(&still));
        assert!(t[6].abs_diff(vb.encode(0.5)) <= 1, "{t:?}");
        // Slots already in the heading (the clip walking forward in them):
        // the take's forward pace, as is.
        let lib = Library::new(vec![vec![walk([180, 180, 180], (0.0, 1.0)); 4]], 9, 360)
            .unwrap()
            .travelling(vb.clone(), true, 1.0);
        let p = walk([180, quarter, 180], (0.0, 1.0));
        let t = lib.target(&p, Some(&p));
        assert!(t[7].abs_diff(vb.encode(1.0)) <= 1 && t[6].abs_diff(vb.encode(0.0)) <= 1);
    }
}
