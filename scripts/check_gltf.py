#!/usr/bin/env python3
"""A converted dance opens as glTF in another reader: choreo writes .glb, the
independent `pygltflib` package reads it, and this script poses the node
tree from the animation's samplers (T·R per node, parents composed) at every
frame. The joints' world positions must match choreo's own forward
kinematics of the same motion (written as choreo JSON by the same convert),
and the joint count, frame count, frame times and skin must be what choreo
wrote.

Usage: check_gltf.py PATH/TO/choreo DATA_DIR
"""
import json, os, subprocess, sys, tempfile
import numpy as np
import pygltflib

exe, data = sys.argv[1], sys.argv[2]
cases = [(os.path.join(data, "aistpp/motions", f), []) for f in sorted(os.listdir(os.path.join(data, "aistpp/motions")))[:2]]
cases.append((os.path.join(data, "bandai/dataset-1/dataset-1_walk_happy_001.bvh"), []))
cases.append((os.path.join(data, "bandai/dataset-1/dataset-1_walk_happy_001.bvh"), ["--joints", "smpl13"]))
cases.append((os.path.join(data, "cmu/01_01.bvh"), []))

COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
DTYPES = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}


def accessor(g, blob, i):
    a = g.accessors[i]
    v = g.bufferViews[a.bufferView]
    n = COMPONENTS[a.type]
    dt = DTYPES[a.componentType]
    start = (v.byteOffset or 0) + (a.byteOffset or 0)
    arr = np.frombuffer(blob, dtype=dt, count=a.count * n, offset=start)
    return arr.reshape(a.count, n) if n > 1 else arr


def quat_mat(q):  # glTF order x, y, z, w
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


fails = 0
with tempfile.TemporaryDirectory() as tmp:
    for src, extra in cases:
        glb, js = os.path.join(tmp, "out.glb"), os.path.join(tmp, "out.json")
        subprocess.run([exe, "convert", src, glb] + extra, check=True, capture_output=True)
        # choreo's FK of the same motion: the source itself, or (after a
        # retarget) the same convert written as choreo JSON.
        ref = src
        if extra:
            subprocess.run([exe, "convert", src, js] + extra, check=True, capture_output=True)
            ref = js
        ours = json.loads(subprocess.run([exe, "positions", ref], check=True, capture_output=True, text=True).stdout)
        names, pos, fps = ours["joints"], np.asarray(ours["positions"]), ours["fps"]
        g = pygltflib.GLTF2().load(glb)
        blob = g.binary_blob()
        skin = g.skins[0]
        joint_nodes = skin.joints
        node_names = [g.nodes[j].name for j in joint_nodes]
        anim = g.animations[0]
        times = accessor(g, blob, anim.samplers[0].input)
        parent = {}
        for i, n in enumerate(g.nodes):
            for c in n.children or []:
                parent[c] = i
        rot = {i: np.tile(np.asarray(n.rotation or [0, 0, 0, 1], float), (len(times), 1)) for i, n in enumerate(g.nodes)}
        tra = {i: np.tile(np.asarray(n.translation or [0, 0, 0], float), (len(times), 1)) for i, n in enumerate(g.nodes)}
        for ch in anim.channels:
            out = accessor(g, blob, anim.samplers[ch.sampler].output).astype(float)
            (rot if ch.target.path == "rotation" else tra)[ch.target.node] = out
        err = 0.0
        for f in range(len(times)):
            glob = {}

            def world(j):
                if j not in glob:
                    R, t = quat_mat(rot[j][f]), tra[j][f]
                    if j in parent:
                        PR, pt = world(parent[j])
                        glob[j] = (PR @ R, pt + PR @ t)
                    else:
                        glob[j] = (R, t)
                return glob[j]

            for k, j in enumerate(joint_nodes):
                err = max(err, float(np.abs(world(j)[1] - pos[f, names.index(node_names[k])]).max()))
        # The skin binds the rest pose: inverse bind matrices undo each
        # joint's rest position.
        ibm = accessor(g, blob, skin.inverseBindMatrices).reshape(-1, 4, 4)
        prim = g.meshes[0].primitives[0]
        weights = accessor(g, blob, prim.attributes.WEIGHTS_0)
        ok = (err < 1e-4 and len(times) == len(pos) and sorted(node_names) == sorted(names)
              and np.allclose(np.diff(times), 1 / fps, atol=1e-5) and len(ibm) == len(names)
              and np.allclose(weights.sum(1), 1.0))
        fails += not ok
        print(f"{'ok' if ok else 'FAIL':4} {os.path.basename(src)} {' '.join(extra)}: {len(times)} frames at "
              f"{fps:g} fps, {len(node_names)} joints, {len(weights)} skinned vertices; "
              f"pygltflib pose vs choreo FK max {err * 1e3:.5f} mm")
print("all glTF files read by pygltflib agree" if not fails else f"{fails} FAILED")
sys.exit(1 if fails else 0)
