//! Binary glTF 2.0 (`.glb`) out: the skeleton as a node tree, a skinned
//! mesh (one octahedral bone from each joint to each child, bound rigidly
//! to the parent), and the motion as one animation (a rotation channel per
//! joint, the root's translation), so three.js's GLTFLoader, Blender and
//! any glTF viewer play it.
//!
//! glTF shares choreo's world (metres, y up, right-handed) and node model
//! (a node's local transform is T·R, children compose), so each joint node
//! is translated by its rest offset and rotated by the frame's local
//! rotation, and the root's translation is `offsets[0] + trans[f]`: the
//! node tree's FK is choreo's FK. Times are `frame / fps`, LINEAR
//! interpolation (spherical for rotations).

use crate::motion::rotation::{axis_angle_to_quat, Vec3};
use crate::motion::{Motion, MotionError};
use serde_json::{json, Value};

const FLOAT: u32 = 5126;
const USHORT: u32 = 5123;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The binary chunk and the JSON views/accessors that describe it.
#[derive(Default)]
struct Bin {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Bin {
    /// Append f32 data as one view + accessor; returns the accessor index.
    fn floats(
        &mut self,
        data: &[f32],
        kind: &str,
        count: usize,
        target: Option<u32>,
        minmax: bool,
    ) -> usize {
        let mut acc = json!({"componentType": FLOAT, "count": count, "type": kind});
        if minmax {
            let width = data.len() / count.max(1);
            let (mut lo, mut hi) = (vec![f32::INFINITY; width], vec![f32::NEG_INFINITY; width]);
            for row in data.chunks(width) {
                for (i, v) in row.iter().enumerate() {
                    lo[i] = lo[i].min(*v);
                    hi[i] = hi[i].max(*v);
                }
            }
            acc["min"] = json!(lo);
            acc["max"] = json!(hi);
        }
        let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.push(raw, acc, target)
    }

    fn ushorts(&mut self, data: &[u16], kind: &str, count: usize, target: Option<u32>) -> usize {
        let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.push(
            raw,
            json!({"componentType": USHORT, "count": count, "type": kind}),
            target,
        )
    }

    fn push(&mut self, raw: Vec<u8>, mut acc: Value, target: Option<u32>) -> usize {
        while self.bytes.len() % 4 != 0 {
            self.bytes.push(0);
        }
        let mut view =
            json!({"buffer": 0, "byteOffset": self.bytes.len(), "byteLength": raw.len()});
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.bytes.extend(raw);
        self.views.push(view);
        acc["bufferView"] = json!(self.views.len() - 1);
        self.accessors.push(acc);
        self.accessors.len() - 1
    }
}

fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn scaled(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn norm(a: Vec3) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// Octahedral bones in the rest pose: (positions, joint per vertex, indices).
fn bones(m: &Motion) -> (Vec<f32>, Vec<u16>, Vec<u16>) {
    let rest = Motion::rest_positions(&m.skeleton);
    let (mut pos, mut joints, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    for (child, parent) in m.skeleton.parents.iter().enumerate() {
        let Some(p) = *parent else { continue };
        let (a, b) = (rest[p], rest[child]);
        let d = sub(b, a);
        let len = norm(d);
        if len < 1e-6 {
            continue;
        }
        let dir = scaled(d, 1.0 / len);
        let helper = if dir[1].abs() < 0.9 {
            [0.0, 1.0, 0.0]
        } else {
            [1.0, 0.0, 0.0]
        };
        let u = cross(dir, helper);
        let u = scaled(u, 1.0 / norm(u));
        let v = cross(dir, u);
        let w = (0.12 * len).min(0.04);
        let mid = [a[0] + 0.2 * d[0], a[1] + 0.2 * d[1], a[2] + 0.2 * d[2]];
        let ring = [
            [mid[0] + w * u[0], mid[1] + w * u[1], mid[2] + w * u[2]],
            [mid[0] + w * v[0], mid[1] + w * v[1], mid[2] + w * v[2]],
            [mid[0] - w * u[0], mid[1] - w * u[1], mid[2] - w * u[2]],
            [mid[0] - w * v[0], mid[1] - w * v[1], mid[2] - w * v[2]],
        ];
        let base = (pos.len() / 3) as u16;
        for q in [a, b].iter().chain(ring.iter()) {
            pos.extend(q.iter().map(|&x| x as f32));
            joints.extend([p as u16, 0, 0, 0]);
        }
        for i in 0..4u16 {
            let (r0, r1) = (base + 2 + i, base + 2 + (i + 1) % 4);
            idx.extend([base, r1, r0]); // towards the parent end
            idx.extend([base + 1, r0, r1]); // towards the child end
        }
    }
    (pos, joints, idx)
}

/// The motion as a binary glTF.
pub fn write_glb(m: &Motion) -> Result<Vec<u8>, MotionError> {
    m.validate()?;
    let sk = &m.skeleton;
    let (nj, nf) = (m.joints(), m.frames());
    if nj > u16::MAX as usize {
        return Err(MotionError::invalid(
            &m.name,
            "skeleton",
            format!("{nj} joints; glTF output takes at most 65,535"),
        ));
    }
    let mut bin = Bin::default();
    let times: Vec<f32> = (0..nf).map(|f| (f as f64 / m.fps) as f32).collect();
    let time_acc = bin.floats(&times, "SCALAR", nf, None, true);
    let quat = |f: usize, j: usize| {
        let q = axis_angle_to_quat(m.rotations[f * nj + j]);
        [q[1] as f32, q[2] as f32, q[3] as f32, q[0] as f32] // glTF: x, y, z, w
    };
    let root_at = |f: usize| -> [f32; 3] {
        let r = sk.parents.iter().position(|p| p.is_none()).unwrap_or(0);
        let t = m.trans[f];
        std::array::from_fn(|i| (sk.offsets[r][i] + t[i]) as f32)
    };
    let mut nodes: Vec<Value> = (0..nj)
        .map(|j| {
            let t: [f32; 3] = if sk.parents[j].is_none() {
                root_at(0)
            } else {
                std::array::from_fn(|i| sk.offsets[j][i] as f32)
            };
            let mut n = json!({"name": sk.names[j], "translation": t, "rotation": quat(0, j)});
            let kids = sk.children(j);
            if !kids.is_empty() {
                n["children"] = json!(kids);
            }
            n
        })
        .collect();
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    for j in 0..nj {
        let q: Vec<f32> = (0..nf).flat_map(|f| quat(f, j)).collect();
        let out = bin.floats(&q, "VEC4", nf, None, false);
        samplers.push(json!({"input": time_acc, "output": out, "interpolation": "LINEAR"}));
        channels.push(
            json!({"sampler": samplers.len() - 1, "target": {"node": j, "path": "rotation"}}),
        );
        if sk.parents[j].is_none() {
            let t: Vec<f32> = (0..nf).flat_map(root_at).collect();
            let out = bin.floats(&t, "VEC3", nf, None, false);
            samplers.push(json!({"input": time_acc, "output": out, "interpolation": "LINEAR"}));
            channels.push(json!({"sampler": samplers.len() - 1, "target": {"node": j, "path": "translation"}}));
        }
    }
    let roots: Vec<usize> = (0..nj).filter(|&j| sk.parents[j].is_none()).collect();
    let mut scene_nodes: Vec<usize> = roots.clone();
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": concat!("choreo ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "animations": [{"name": m.name, "samplers": samplers, "channels": channels}],
    });
    let (pos, joints, idx) = bones(m);
    if !idx.is_empty() {
        let nv = pos.len() / 3;
        let pos_acc = bin.floats(&pos, "VEC3", nv, Some(ARRAY_BUFFER), true);
        let joint_acc = bin.ushorts(&joints, "VEC4", nv, Some(ARRAY_BUFFER));
        let weights: Vec<f32> = (0..nv).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect();
        let weight_acc = bin.floats(&weights, "VEC4", nv, Some(ARRAY_BUFFER), false);
        let idx_acc = bin.ushorts(&idx, "SCALAR", idx.len(), Some(ELEMENT_ARRAY_BUFFER));
        // Rest globals are pure translations: their inverses negate them.
        let rest = Motion::rest_positions(sk);
        let ibm: Vec<f32> = rest
            .iter()
            .flat_map(|p| {
                [
                    1.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    1.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    1.0,
                    0.0,
                    -p[0] as f32,
                    -p[1] as f32,
                    -p[2] as f32,
                    1.0,
                ]
            })
            .collect();
        let ibm_acc = bin.floats(&ibm, "MAT4", nj, None, false);
        nodes.push(json!({"name": "bones", "mesh": 0, "skin": 0}));
        scene_nodes.push(nodes.len() - 1);
        doc["meshes"] = json!([{"name": "bones", "primitives": [{
            "attributes": {"POSITION": pos_acc, "JOINTS_0": joint_acc, "WEIGHTS_0": weight_acc},
            "indices": idx_acc, "material": 0}]}]);
        doc["materials"] = json!([{"name": "bone", "pbrMetallicRoughness": {
            "baseColorFactor": [0.85, 0.55, 0.25, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.8}}]);
        doc["skins"] = json!([{"name": sk.kind, "joints": (0..nj).collect::<Vec<_>>(),
                               "skeleton": roots[0], "inverseBindMatrices": ibm_acc}]);
    }
    doc["nodes"] = json!(nodes);
    doc["scenes"] = json!([{"name": m.name, "nodes": scene_nodes}]);
    while bin.bytes.len() % 4 != 0 {
        bin.bytes.push(0);
    }
    doc["buffers"] = json!([{"byteLength": bin.bytes.len()}]);
    doc["bufferViews"] = json!(bin.views);
    doc["accessors"] = json!(bin.accessors);
    let mut text = serde_json::to_vec(&doc).expect("glTF JSON serialises");
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + 8 + bin.bytes.len();
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((text.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(text);
    out.extend((bin.bytes.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin.bytes);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{Labels, Skeleton};

    /// The container is well formed: header, two aligned chunks, lengths
    /// that add up, a JSON chunk that parses and names every joint.
    #[test]
    fn glb_container_is_well_formed() {
        let frames = 5;
        let rots: Vec<Vec3> = (0..frames * 24)
            .map(|i| [0.01 * i as f64, 0.0, 0.0])
            .collect();
        let m = Motion::new(
            "t",
            30.0,
            Skeleton::smpl24(),
            vec![[0.0, 0.9, 0.0]; frames],
            rots,
            Labels::new(),
        )
        .unwrap();
        let b = write_glb(&m).unwrap();
        assert_eq!(&b[0..4], b"glTF");
        assert_eq!(
            u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize,
            b.len()
        );
        let jl = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
        assert_eq!(&b[16..20], b"JSON");
        assert_eq!(jl % 4, 0);
        let doc: Value = serde_json::from_slice(&b[20..20 + jl]).unwrap();
        let bl = u32::from_le_bytes(b[20 + jl..24 + jl].try_into().unwrap()) as usize;
        assert_eq!(&b[24 + jl..28 + jl], b"BIN\0");
        assert_eq!(28 + jl + bl, b.len());
        assert_eq!(doc["buffers"][0]["byteLength"], bl);
        assert_eq!(doc["skins"][0]["joints"].as_array().unwrap().len(), 24);
        assert_eq!(doc["nodes"][0]["name"], "Pelvis");
        assert_eq!(doc["accessors"][0]["count"], frames);
    }
}
