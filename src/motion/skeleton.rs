//! Skeletons: joint names, parents and rest offsets (metres, in the parent's
//! frame, y up). The SMPL 24-joint tree is written in as constants (from
//! `shared/data/smpl/skeleton_neutral.json`, the neutral body); the 13-joint
//! subset of thesis 000 Table A.1 is derived from it.

use super::rotation::{add, Vec3};
use super::MotionError;
use serde::{Deserialize, Serialize};

/// The SMPL neutral skeleton: (name, parent index or -1, rest offset in metres).
/// The root's offset is the pelvis location in the rest pose.
pub const SMPL24_JOINTS: [(&str, i32, Vec3); 24] = [
    (
        "Pelvis",
        -1,
        [
            -0.0017950618639588356,
            -0.2233334481716156,
            0.028219128027558327,
        ],
    ),
    (
        "Left_Hip",
        0,
        [
            0.06951973587274551,
            -0.09140622615814209,
            -0.006815336644649506,
        ],
    ),
    (
        "Right_Hip",
        0,
        [
            -0.06767047941684723,
            -0.09052169322967529,
            -0.004319826140999794,
        ],
    ),
    (
        "Spine1",
        0,
        [
            -0.0025328658521175385,
            0.10896322876214981,
            -0.02669631689786911,
        ],
    ),
    (
        "Left_Knee",
        1,
        [
            0.03427654504776001,
            -0.3751985728740692,
            -0.004495805129408836,
        ],
    ),
    (
        "Right_Knee",
        2,
        [
            -0.038290053606033325,
            -0.38256898522377014,
            -0.008850027807056904,
        ],
    ),
    (
        "Spine2",
        3,
        [
            0.00548703595995903,
            0.13518042862415314,
            0.0010924721136689186,
        ],
    ),
    (
        "Left_Ankle",
        4,
        [
            -0.01359570026397705,
            -0.39796048402786255,
            -0.04369333013892174,
        ],
    ),
    (
        "Right_Ankle",
        5,
        [
            0.015773765742778778,
            -0.3984147310256958,
            -0.04231179878115654,
        ],
    ),
    (
        "Spine3",
        6,
        [
            0.0014569992199540138,
            0.05292222648859024,
            0.025424566119909286,
        ],
    ),
    (
        "Left_Foot",
        7,
        [
            0.026358142495155334,
            -0.05579078197479248,
            0.11928839981555939,
        ],
    ),
    (
        "Right_Foot",
        8,
        [
            -0.025371752679347992,
            -0.048143863677978516,
            0.12334795296192169,
        ],
    ),
    (
        "Neck",
        9,
        [
            -0.0027783922851085663,
            0.21387037634849548,
            -0.042857032269239426,
        ],
    ),
    (
        "Left_Collar",
        9,
        [
            0.07884473353624344,
            0.12174931168556213,
            -0.034089602530002594,
        ],
    ),
    (
        "Right_Collar",
        9,
        [
            -0.08175919204950333,
            0.11883285641670227,
            -0.03861527889966965,
        ],
    ),
    (
        "Head",
        12,
        [
            0.005151841789484024,
            0.06496959924697876,
            0.0513489656150341,
        ],
    ),
    (
        "Left_Shoulder",
        13,
        [
            0.09097693115472794,
            0.030468910932540894,
            -0.008868152275681496,
        ],
    ),
    (
        "Right_Shoulder",
        14,
        [
            -0.09601237624883652,
            0.03255116939544678,
            -0.009143071249127388,
        ],
    ),
    (
        "Left_Elbow",
        16,
        [
            0.25961220264434814,
            -0.012772083282470703,
            -0.027456430718302727,
        ],
    ),
    (
        "Right_Elbow",
        17,
        [
            -0.253741979598999,
            -0.013329237699508667,
            -0.02140098623931408,
        ],
    ),
    (
        "Left_Wrist",
        18,
        [
            0.24923360347747803,
            0.008986026048660278,
            -0.001170918345451355,
        ],
    ),
    (
        "Right_Wrist",
        19,
        [
            -0.25529801845550537,
            0.007772296667098999,
            -0.005559191107749939,
        ],
    ),
    (
        "Left_Palm",
        20,
        [
            0.08404213190078735,
            -0.0081615149974823,
            -0.014945365488529205,
        ],
    ),
    (
        "Right_Palm",
        21,
        [
            -0.08462196588516235,
            -0.0061172544956207275,
            -0.01031508669257164,
        ],
    ),
];

/// Indices into [`SMPL24_JOINTS`] of the 13 joints of thesis 000 Table A.1, in
/// SMPL order: pelvis, L/R hip, L/R knee, L/R ankle, L/R shoulder, L/R elbow,
/// L/R wrist.
pub const SMPL13_FROM_24: [usize; 13] = [0, 1, 2, 4, 5, 7, 8, 16, 17, 18, 19, 20, 21];

/// A joint that ends a chain in a BVH file (`End Site`): kept so that BVH
/// files round-trip.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EndSite {
    pub parent: usize,
    pub offset: Vec3,
}

/// A kinematic tree. Joints are stored parents-first (every parent index is
/// smaller than its child's), which forward kinematics relies on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    /// "smpl24", "smpl13", or "custom" for any other tree (e.g. a BVH's).
    pub kind: String,
    pub names: Vec<String>,
    pub parents: Vec<Option<usize>>,
    /// Rest offsets in metres, each in its parent's frame; the root's offset
    /// is its rest position in the world.
    pub offsets: Vec<Vec3>,
    #[serde(default)]
    pub end_sites: Vec<EndSite>,
}

impl Skeleton {
    pub fn new(
        kind: &str,
        names: Vec<String>,
        parents: Vec<Option<usize>>,
        offsets: Vec<Vec3>,
        end_sites: Vec<EndSite>,
    ) -> Result<Self, MotionError> {
        let s = Skeleton {
            kind: kind.to_string(),
            names,
            parents,
            offsets,
            end_sites,
        };
        s.validate()?;
        Ok(s)
    }

    pub fn smpl24() -> Self {
        Skeleton {
            kind: "smpl24".into(),
            names: SMPL24_JOINTS.iter().map(|j| j.0.to_string()).collect(),
            parents: SMPL24_JOINTS
                .iter()
                .map(|j| if j.1 < 0 { None } else { Some(j.1 as usize) })
                .collect(),
            offsets: SMPL24_JOINTS.iter().map(|j| j.2).collect(),
            end_sites: Vec::new(),
        }
    }

    /// The 13-joint subset: each kept joint's parent is its nearest kept
    /// ancestor and its offset is the sum of the rest offsets along the dropped
    /// chain (so the rest pose is the same body).
    pub fn smpl13() -> Self {
        let full = Self::smpl24();
        full.subset(&SMPL13_FROM_24, "smpl13")
            .expect("the SMPL 13-joint subset is a valid tree")
    }

    pub fn len(&self) -> usize {
        self.names.len()
    }
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    pub fn children(&self, j: usize) -> Vec<usize> {
        (0..self.len())
            .filter(|&c| self.parents[c] == Some(j))
            .collect()
    }

    /// A tree keeping only `keep` (indices into `self`, ascending, root
    /// included). Offsets of dropped joints are folded into their kept
    /// descendants.
    pub fn subset(&self, keep: &[usize], kind: &str) -> Result<Skeleton, MotionError> {
        if keep.first() != Some(&0) {
            return Err(MotionError::invalid(
                "skeleton",
                "joints",
                "a joint subset must keep the root first",
            ));
        }
        if keep.windows(2).any(|w| w[0] >= w[1]) || keep.iter().any(|&k| k >= self.len()) {
            return Err(MotionError::invalid(
                "skeleton",
                "joints",
                "a joint subset must list valid joint indices in ascending order",
            ));
        }
        let mut names = Vec::new();
        let mut parents = Vec::new();
        let mut offsets = Vec::new();
        for &k in keep {
            names.push(self.names[k].clone());
            let mut off = self.offsets[k];
            let mut p = self.parents[k];
            let mut new_parent = None;
            while let Some(pi) = p {
                if let Some(pos) = keep.iter().position(|&x| x == pi) {
                    new_parent = Some(pos);
                    break;
                }
                off = add(off, self.offsets[pi]);
                p = self.parents[pi];
            }
            parents.push(new_parent);
            offsets.push(off);
        }
        Skeleton::new(kind, names, parents, offsets, Vec::new())
    }

    pub fn validate(&self) -> Result<(), MotionError> {
        let n = self.names.len();
        if n == 0 {
            return Err(MotionError::invalid("skeleton", "joints", "no joints"));
        }
        if self.parents.len() != n || self.offsets.len() != n {
            return Err(MotionError::invalid(
                "skeleton",
                "parents",
                format!(
                    "{} names, {} parents, {} offsets",
                    n,
                    self.parents.len(),
                    self.offsets.len()
                ),
            ));
        }
        if self.parents[0].is_some() {
            return Err(MotionError::invalid(
                "skeleton",
                "parents",
                "joint 0 must be the root",
            ));
        }
        for (j, p) in self.parents.iter().enumerate().skip(1) {
            match p {
                None => {
                    return Err(MotionError::invalid(
                        "skeleton",
                        "parents",
                        format!("joint {j} ('{}') is a second root", self.names[j]),
                    ))
                }
                Some(p) if *p >= j => {
                    return Err(MotionError::invalid(
                        "skeleton",
                        "parents",
                        format!(
                            "joint {j} ('{}') has parent {p}, not before it",
                            self.names[j]
                        ),
                    ))
                }
                _ => {}
            }
        }
        for (j, o) in self.offsets.iter().enumerate() {
            if o.iter().any(|v| !v.is_finite()) {
                return Err(MotionError::invalid(
                    "skeleton",
                    "offsets",
                    format!("joint {j} ('{}') has a non-finite offset", self.names[j]),
                ));
            }
        }
        for e in &self.end_sites {
            if e.parent >= n {
                return Err(MotionError::invalid(
                    "skeleton",
                    "end_sites",
                    "parent out of range",
                ));
            }
        }
        Ok(())
    }

    /// Pairs of left/right joints found by name (`Left_X`/`Right_X`,
    /// `LeftX`/`RightX`, `X_L`/`X_R`, `LX`/`RX`, `l_x`/`r_x`), each pair once.
    pub fn mirror_pairs(&self) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        for (i, name) in self.names.iter().enumerate() {
            if let Some(other) = mirrored_name(name) {
                if let Some(j) = self.index_of(&other) {
                    if i < j {
                        pairs.push((i, j));
                    }
                }
            }
        }
        pairs
    }

    /// For each joint, the index of its mirror partner (itself if unpaired).
    pub fn mirror_map(&self) -> Vec<usize> {
        let mut map: Vec<usize> = (0..self.len()).collect();
        for (a, b) in self.mirror_pairs() {
            map[a] = b;
            map[b] = a;
        }
        map
    }
}

/// `Some(true)` for a left joint, `Some(false)` for a right one, by name.
pub fn is_left(name: &str) -> Option<bool> {
    let other = mirrored_name(name)?;
    let lower = name.to_ascii_lowercase();
    let other_lower = other.to_ascii_lowercase();
    // The side is whatever the swap removed: find the first differing char.
    let pos = lower
        .bytes()
        .zip(other_lower.bytes())
        .position(|(a, b)| a != b)?;
    Some(lower.as_bytes()[pos] == b'l')
}

/// The name a joint's left/right partner would have, if the name says a side.
pub fn mirrored_name(name: &str) -> Option<String> {
    const SWAPS: [(&str, &str); 4] = [
        ("Left", "Right"),
        ("left", "right"),
        ("LEFT", "RIGHT"),
        ("Right", "Left"),
    ];
    for (a, b) in SWAPS {
        if let Some(rest) = name.strip_prefix(a) {
            return Some(format!("{b}{rest}"));
        }
    }
    for (a, b) in [("right", "left"), ("RIGHT", "LEFT")] {
        if let Some(rest) = name.strip_prefix(a) {
            return Some(format!("{b}{rest}"));
        }
    }
    for (a, b) in [
        ("_L", "_R"),
        ("_R", "_L"),
        ("_l", "_r"),
        ("_r", "_l"),
        (".L", ".R"),
        (".R", ".L"),
    ] {
        if let Some(rest) = name.strip_suffix(a) {
            return Some(format!("{rest}{b}"));
        }
    }
    for (a, b) in [("l_", "r_"), ("r_", "l_"), ("L_", "R_"), ("R_", "L_")] {
        if let Some(rest) = name.strip_prefix(a) {
            return Some(format!("{b}{rest}"));
        }
    }
    // CMU style: LHipJoint / RHipJoint, LThumb / RThumb (an upper-case L or R
    // followed by another upper-case letter).
    let mut chars = name.chars();
    if let (Some(c0), Some(c1)) = (chars.next(), chars.next()) {
        if (c0 == 'L' || c0 == 'R') && c1.is_ascii_uppercase() {
            let other = if c0 == 'L' { 'R' } else { 'L' };
            return Some(format!("{other}{}", &name[1..]));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smpl13_folds_offsets_of_dropped_joints() {
        let s = Skeleton::smpl13();
        assert_eq!(s.len(), 13);
        let ls = s.index_of("Left_Shoulder").unwrap();
        assert_eq!(s.parents[ls], Some(0));
        // Spine1 + Spine2 + Spine3 + Left_Collar + Left_Shoulder offsets.
        let full = Skeleton::smpl24();
        let mut expect = [0.0; 3];
        for j in [3, 6, 9, 13, 16] {
            expect = add(expect, full.offsets[j]);
        }
        for k in 0..3 {
            assert!((s.offsets[ls][k] - expect[k]).abs() < 1e-15);
        }
    }

    #[test]
    fn mirror_pairs_of_smpl_and_bvh_names() {
        let s = Skeleton::smpl24();
        assert_eq!(s.mirror_pairs().len(), 9);
        assert_eq!(mirrored_name("UpperArm_L").as_deref(), Some("UpperArm_R"));
        assert_eq!(mirrored_name("LeftUpLeg").as_deref(), Some("RightUpLeg"));
        assert_eq!(mirrored_name("LHipJoint").as_deref(), Some("RHipJoint"));
        assert_eq!(mirrored_name("LowerBack"), None);
        assert_eq!(mirrored_name("Hips"), None);
        assert_eq!(is_left("LowerLeg_R"), Some(false));
        assert_eq!(is_left("LowerLeg_L"), Some(true));
        assert_eq!(is_left("Right_Hip"), Some(false));
        assert_eq!(is_left("LHipJoint"), Some(true));
    }
}
