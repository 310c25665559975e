//! Retargeting any BVH skeleton onto the SMPL 13-joint model subset.
//!
//! A joint map names, for each SMPL joint used, the source joint standing for
//! it (built-in aliases cover the Bandai Namco and CMU skeletons and common
//! Mixamo/MotionBuilder names; a JSON object overrides them).
//!
//! Rest-pose alignment: for every target joint `t` with source joint `s`, the
//! rotation `A_t` is the orientation the source joint would have if the source
//! body stood in SMPL's rest pose. For limbs it is the shortest-arc rotation
//! taking the source rest bone direction (`s` → source of `t`'s child) onto
//! SMPL's; for the pelvis it aligns two directions (up to the neck, and right
//! hip → left hip), which fixes the heading too. Then per frame the target's
//! global rotation is `G_t = G_s · A_t⁻¹`: the same physical pose gives the
//! same rotations whatever the source's rest pose (every target bone points
//! where its source bone points). Twist about a limb's own axis is not
//! observable from a rest pose and is carried over as the source has it.
//!
//! Assumes the source world is y up (true of BVH from Bandai Namco, CMU,
//! Mixamo and MotionBuilder exports).

use super::clip::Motion;
use super::rotation::*;
use super::skeleton::{mirrored_name, Skeleton, SMPL13_FROM_24};
use super::MotionError;
use std::collections::BTreeMap;

/// SMPL joints a retarget needs: the 13 of Table A.1, plus `Left/Right_Foot`
/// and `Neck` as direction references (ankle → toe, pelvis → neck).
const NEEDED: [&str; 15] = [
    "Pelvis",
    "Left_Hip",
    "Right_Hip",
    "Left_Knee",
    "Right_Knee",
    "Left_Ankle",
    "Right_Ankle",
    "Left_Shoulder",
    "Right_Shoulder",
    "Left_Elbow",
    "Right_Elbow",
    "Left_Wrist",
    "Right_Wrist",
    "Left_Foot",
    "Right_Foot",
];

/// Source-name aliases of left/centre SMPL joints (right ones are mirrored).
const ALIASES: [(&str, &[&str]); 9] = [
    ("Pelvis", &["Hips", "Pelvis", "Hip", "mixamorig:Hips"]),
    ("Neck", &["Neck", "Neck1", "mixamorig:Neck"]),
    (
        "Left_Hip",
        &[
            "UpperLeg_L",
            "LeftUpLeg",
            "Left_Hip",
            "LeftHip",
            "LeftThigh",
            "L_Hip",
            "lThigh",
        ],
    ),
    (
        "Left_Knee",
        &[
            "LowerLeg_L",
            "LeftLeg",
            "Left_Knee",
            "LeftKnee",
            "LeftShin",
            "L_Knee",
            "lShin",
        ],
    ),
    (
        "Left_Ankle",
        &[
            "Foot_L",
            "LeftFoot",
            "Left_Ankle",
            "LeftAnkle",
            "L_Ankle",
            "lFoot",
        ],
    ),
    (
        "Left_Foot",
        &[
            "Toes_L",
            "LeftToeBase",
            "Left_Foot",
            "LeftToe",
            "LeftToes",
            "L_Foot",
        ],
    ),
    // CMU's "LeftShoulder" is the collar bone; its upper arm is "LeftArm".
    (
        "Left_Shoulder",
        &[
            "UpperArm_L",
            "LeftArm",
            "Left_Shoulder",
            "LeftUpArm",
            "L_Shoulder",
            "lShldr",
        ],
    ),
    (
        "Left_Elbow",
        &[
            "LowerArm_L",
            "LeftForeArm",
            "Left_Elbow",
            "LeftElbow",
            "L_Elbow",
            "lForeArm",
        ],
    ),
    (
        "Left_Wrist",
        &[
            "Hand_L",
            "LeftHand",
            "Left_Wrist",
            "LeftWrist",
            "L_Wrist",
            "lHand",
        ],
    ),
];

/// SMPL joint name → source joint name.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct JointMap(pub BTreeMap<String, String>);

impl JointMap {
    /// Resolve the built-in aliases against a source skeleton (case-insensitive,
    /// with or without a `mixamorig:` style prefix), then apply `overrides`.
    pub fn resolve(
        source: &Skeleton,
        overrides: &BTreeMap<String, String>,
    ) -> Result<JointMap, MotionError> {
        let find = |cands: &[String]| -> Option<String> {
            for c in cands {
                for n in &source.names {
                    let bare = n.rsplit(':').next().unwrap_or(n);
                    if n.eq_ignore_ascii_case(c) || bare.eq_ignore_ascii_case(c) {
                        return Some(n.clone());
                    }
                }
            }
            None
        };
        let mut map = BTreeMap::new();
        for (target, cands) in ALIASES.iter() {
            let cands: Vec<String> = cands.iter().map(|s| s.to_string()).collect();
            if let Some(src) = find(&cands) {
                map.insert(target.to_string(), src);
            }
            if let Some(right) = mirrored_name(target) {
                let rc: Vec<String> = cands.iter().filter_map(|c| mirrored_name(c)).collect();
                if let Some(src) = find(&rc) {
                    map.insert(right, src);
                }
            }
        }
        for (t, s) in overrides {
            if !NEEDED.contains(&t.as_str()) && t != "Neck" {
                return Err(MotionError::invalid(
                    "joint map",
                    t,
                    format!(
                        "'{t}' is not an SMPL joint a retarget uses ({})",
                        NEEDED.join(", ")
                    ),
                ));
            }
            if source.index_of(s).is_none() {
                return Err(MotionError::invalid(
                    "joint map",
                    t,
                    format!("source joint '{s}' is not in the skeleton"),
                ));
            }
            map.insert(t.clone(), s.clone());
        }
        let missing: Vec<&str> = NEEDED
            .iter()
            .chain(["Neck"].iter())
            .filter(|n| !map.contains_key(**n))
            .copied()
            .collect();
        if !missing.is_empty() {
            return Err(MotionError::invalid(
                "joint map",
                missing[0],
                format!(
                    "no source joint found for {}; the skeleton has [{}] — pass a joint map",
                    missing.join(", "),
                    source.names.join(", ")
                ),
            ));
        }
        Ok(JointMap(map))
    }
}

fn dir(a: Vec3, b: Vec3, what: &str) -> Result<Vec3, MotionError> {
    normalize(sub(b, a))
        .ok_or_else(|| MotionError::invalid("retarget", what, "zero-length bone in the rest pose"))
}

/// The rotation taking the orthonormal frame built from (primary `p`,
/// secondary `s`) in one space onto the frame from (`p2`, `s2`) in another.
fn two_vector_align(p: Vec3, s: Vec3, p2: Vec3, s2: Vec3) -> Result<Quat, MotionError> {
    let frame = |p: Vec3, s: Vec3| -> Result<Mat3, MotionError> {
        let x = normalize(p)
            .ok_or_else(|| MotionError::invalid("retarget", "Pelvis", "degenerate frame"))?;
        let z = normalize(cross(x, s)).ok_or_else(|| {
            MotionError::invalid("retarget", "Pelvis", "hips line parallel to spine")
        })?;
        let y = cross(z, x);
        // Columns x, y, z.
        Ok([[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]])
    };
    let a = frame(p, s)?;
    let b = frame(p2, s2)?;
    Ok(mat_to_quat(&mat_mul(&b, &transpose(&a))))
}

/// Retarget a motion on any skeleton onto the SMPL 13-joint subset.
pub fn retarget_to_smpl13(src: &Motion, map: &JointMap) -> Result<Motion, MotionError> {
    let file = src.name.as_str();
    let sk = &src.skeleton;
    let idx = |smpl: &str| -> Result<usize, MotionError> {
        let name = map
            .0
            .get(smpl)
            .ok_or_else(|| MotionError::invalid(file, smpl, "not in the joint map"))?;
        sk.index_of(name).ok_or_else(|| {
            MotionError::invalid(
                file,
                smpl,
                format!("source joint '{name}' is not in the skeleton"),
            )
        })
    };
    let full = Skeleton::smpl24();
    let tgt_rest = Motion::rest_positions(&full);
    let src_rest = Motion::rest_positions(sk);
    let smpl_idx = |n: &str| full.index_of(n).expect("SMPL joint name");
    let t13 = Skeleton::smpl13();
    // Alignment per target joint (index into the 13).
    let mut align = vec![IDENTITY_QUAT; 13];
    let mut src_of = vec![0usize; 13];
    for (i, &k) in SMPL13_FROM_24.iter().enumerate() {
        let name = full.names[k].as_str();
        src_of[i] = idx(name)?;
        if name == "Pelvis" {
            let s_up = dir(src_rest[idx("Pelvis")?], src_rest[idx("Neck")?], "Neck")?;
            let s_lat = dir(
                src_rest[idx("Right_Hip")?],
                src_rest[idx("Left_Hip")?],
                "Left_Hip",
            )?;
            let t_up = dir(tgt_rest[0], tgt_rest[smpl_idx("Neck")], "Neck")?;
            let t_lat = dir(
                tgt_rest[smpl_idx("Right_Hip")],
                tgt_rest[smpl_idx("Left_Hip")],
                "Left_Hip",
            )?;
            align[i] = two_vector_align(s_up, s_lat, t_up, t_lat)?;
            continue;
        }
        // The child whose direction defines the bone.
        let child = match name {
            "Left_Hip" => Some("Left_Knee"),
            "Right_Hip" => Some("Right_Knee"),
            "Left_Knee" => Some("Left_Ankle"),
            "Right_Knee" => Some("Right_Ankle"),
            "Left_Ankle" => Some("Left_Foot"),
            "Right_Ankle" => Some("Right_Foot"),
            "Left_Shoulder" => Some("Left_Elbow"),
            "Right_Shoulder" => Some("Right_Elbow"),
            "Left_Elbow" => Some("Left_Wrist"),
            "Right_Elbow" => Some("Right_Wrist"),
            _ => None, // wrists: the hand's own child in the source
        };
        let s = src_of[i];
        let (s_dir, t_dir) = match child {
            Some(c) => (
                dir(src_rest[s], src_rest[idx(c)?], c)?,
                dir(tgt_rest[k], tgt_rest[smpl_idx(c)], c)?,
            ),
            None => {
                let palm = smpl_idx(if name.starts_with("Left") {
                    "Left_Palm"
                } else {
                    "Right_Palm"
                });
                let t_dir = dir(tgt_rest[k], tgt_rest[palm], name)?;
                // First child joint, else first End Site, else the forearm's line.
                let s_child = sk
                    .children(s)
                    .first()
                    .map(|&c| sk.offsets[c])
                    .or_else(|| {
                        sk.end_sites
                            .iter()
                            .find(|e| e.parent == s)
                            .map(|e| e.offset)
                    })
                    .filter(|o| norm(*o) > 1e-9)
                    .unwrap_or(sk.offsets[s]);
                (dir([0.0; 3], s_child, name)?, t_dir)
            }
        };
        align[i] = quat_between(s_dir, t_dir);
    }
    // Scale: SMPL leg length over the source's (hip → knee → ankle).
    let leg = |rest: &[Vec3], h: usize, k: usize, a: usize| {
        norm(sub(rest[k], rest[h])) + norm(sub(rest[a], rest[k]))
    };
    let src_leg = leg(
        &src_rest,
        idx("Left_Hip")?,
        idx("Left_Knee")?,
        idx("Left_Ankle")?,
    );
    let tgt_leg = leg(&tgt_rest, 1, 4, 7);
    if src_leg < 1e-6 {
        return Err(MotionError::invalid(
            file,
            "Left_Knee",
            "the source leg has no length",
        ));
    }
    let k_scale = tgt_leg / src_leg;
    let g = src.global_quats();
    let pos = src.positions();
    let nj = sk.len();
    let o0 = t13.offsets[0];
    let mut rots = Vec::with_capacity(src.frames() * 13);
    let mut trans = Vec::with_capacity(src.frames());
    let mut gt = [IDENTITY_QUAT; 13];
    for f in 0..src.frames() {
        for i in 0..13 {
            gt[i] = quat_mul(g[f * nj + src_of[i]], quat_conj(align[i]));
        }
        for i in 0..13 {
            let local = match t13.parents[i] {
                None => gt[i],
                Some(p) => quat_mul(quat_conj(gt[p]), gt[i]),
            };
            rots.push(quat_to_axis_angle(local));
        }
        trans.push(sub(scale(pos[f * nj + src_of[0]], k_scale), o0));
    }
    let mut labels = src.labels.clone();
    labels.insert("retargeted_from".into(), "bvh".into());
    Motion::new(file, src.fps, t13, trans, rots, labels)
}

/// The largest angle (radians) between a retargeted bone and its source bone
/// over all frames, per limb bone: how well directions were carried over.
pub fn bone_direction_error(
    src: &Motion,
    out: &Motion,
    map: &JointMap,
) -> Result<f64, MotionError> {
    let sp = src.positions();
    let tp = out.positions();
    let sk13 = &out.skeleton;
    let mut worst = 0.0f64;
    for (i, &k) in SMPL13_FROM_24.iter().enumerate().skip(1) {
        let name = &Skeleton::smpl24().names[k];
        let Some(p) = sk13.parents[i] else { continue };
        // Only bones between two mapped joints whose parent is their SMPL-13
        // parent in the source too (hips/shoulders hang off the pelvis by
        // different chains, so skip those).
        if p == 0 {
            continue;
        }
        let parent_name = &sk13.names[p];
        let (Some(sa), Some(sb)) = (map.0.get(parent_name), map.0.get(name)) else {
            continue;
        };
        let (Some(a), Some(b)) = (src.skeleton.index_of(sa), src.skeleton.index_of(sb)) else {
            continue;
        };
        for f in 0..src.frames() {
            let ds = normalize(sub(sp[f * src.joints() + b], sp[f * src.joints() + a]));
            let dt = normalize(sub(tp[f * 13 + i], tp[f * 13 + p]));
            if let (Some(ds), Some(dt)) = (ds, dt) {
                worst = worst.max(dot(ds, dt).clamp(-1.0, 1.0).acos());
            }
        }
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::clip::tests::sine_clip;

    /// The SMPL body re-expressed on a skeleton whose rest frames are turned
    /// (every joint j carries a rest rotation C_j, like Bandai's bones-along-x
    /// rest pose): same world pose, different local rotations and offsets.
    fn reposed_source(m: &Motion) -> Motion {
        let sk = &m.skeleton;
        let mut c: Vec<Quat> = (0..sk.len())
            .map(|j| axis_angle_to_quat([0.3 * (j as f64).sin(), 0.9, -0.4 * (j as f64).cos()]))
            .collect();
        // The spine's rest segments share the pelvis's frame (as in real
        // rigs), so the source's rest pelvis→neck line is the SMPL one turned.
        for j in [3, 6, 9] {
            c[j] = c[0];
        }
        let mut offsets = sk.offsets.clone();
        for j in 1..sk.len() {
            let p = sk.parents[j].unwrap();
            offsets[j] = quat_rotate(quat_conj(c[p]), sk.offsets[j]);
        }
        let mut rots = m.rotations.clone();
        for f in 0..m.frames() {
            for j in 0..sk.len() {
                let l = axis_angle_to_quat(m.rot(f, j));
                let q = match sk.parents[j] {
                    None => quat_mul(l, c[j]),
                    Some(p) => quat_mul(quat_mul(quat_conj(c[p]), l), c[j]),
                };
                rots[f * sk.len() + j] = quat_to_axis_angle(q);
            }
        }
        let sk2 = Skeleton::new(
            "custom",
            sk.names.clone(),
            sk.parents.clone(),
            offsets,
            vec![],
        )
        .unwrap();
        Motion::new(
            "reposed",
            m.fps,
            sk2,
            m.trans.clone(),
            rots,
            m.labels.clone(),
        )
        .unwrap()
    }

    #[test]
    fn reposed_rest_frames_give_the_same_bone_directions() {
        let m = sine_clip(30, 30.0);
        let src = reposed_source(&m);
        // Same world positions by construction.
        let (a, b) = (m.positions(), src.positions());
        assert!(a.iter().zip(&b).all(|(x, y)| norm(sub(*x, *y)) < 1e-9));
        let map = JointMap::resolve(&src.skeleton, &BTreeMap::new()).unwrap();
        let out = retarget_to_smpl13(&src, &map).unwrap();
        let err = bone_direction_error(&src, &out, &map).unwrap();
        assert!(err < 1e-6, "bone direction error {err} rad");
        // And the pelvis orientation is recovered exactly (two-vector fit).
        let direct = m.to_smpl13().unwrap();
        for f in 0..30 {
            assert!(geodesic_axis_angle(direct.rot(f, 0), out.rot(f, 0)) < 1e-6);
        }
    }

    #[test]
    fn missing_joints_are_named() {
        let sk = Skeleton::new(
            "custom",
            vec!["Hips".into()],
            vec![None],
            vec![[0.0; 3]],
            vec![],
        )
        .unwrap();
        let e = JointMap::resolve(&sk, &BTreeMap::new())
            .unwrap_err()
            .to_string();
        assert!(e.contains("Left_Hip"), "{e}");
    }
}
