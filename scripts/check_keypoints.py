#!/usr/bin/env python3
"""Keypoints and inverse kinematics against numpy + scipy.

1. choreo makes clean Human3.6M-17 and MediaPipe-33 keypoints from a real
   AIST++ take (`choreo footage synth --clean --fps 60`). This script reads
   the same pickle itself, runs SMPL forward kinematics with scipy's
   rotations on the neutral skeleton (shared/data/smpl), places the same
   points (joints, and points fixed in the head / wrist / ankle / foot
   frames) and turns them into camera axes (x, -y, -z). The two must agree
   to float32 precision.
2. choreo solves the keypoints back (`choreo convert KP.npy OUT.json
   --keypoints ... --source-fps 60 --smooth 0`). This script poses the solved
   rotations with its own FK; every limb bone (thigh, shin, upper arm,
   forearm) must point where the keypoints say, and the root must sit at
   the pelvis keypoint (scale recovered from bone lengths: the keypoints
   are written in millimetres).

Usage: check_keypoints.py PATH/TO/choreo DATA_DIR
"""
import json, os, pickle, subprocess, sys, tempfile
import numpy as np
from scipy.spatial.transform import Rotation as R

exe, data = sys.argv[1], sys.argv[2]
sk = json.load(open(os.path.join(data, "smpl/skeleton_neutral.json")))
parents, offsets = sk["parents"], np.asarray(sk["offsets"])
take = os.path.join(data, "aistpp/motions", sorted(os.listdir(os.path.join(data, "aistpp/motions")))[0])


def fk(rotvec, trans):
    """rotvec (T, 24, 3), trans (T, 3) -> positions (T, 24, 3), global rotations."""
    T = rotvec.shape[0]
    pos = np.zeros((T, 24, 3))
    glob = [None] * 24
    for j in range(24):
        local = R.from_rotvec(rotvec[:, j])
        if parents[j] < 0:
            glob[j] = local
            pos[:, j] = offsets[j] + trans
        else:
            p = parents[j]
            glob[j] = glob[p] * local
            pos[:, j] = pos[:, p] + glob[p].apply(offsets[j])
    return pos, glob


def head(x, y, z):
    return ("off", 15, (x, y, z))


J = lambda j: ("joint", j)
H36M = [J(0), J(2), J(5), J(8), J(1), J(4), J(7), J(6), J(12), head(0, 0, 0.10), head(0, 0.12, 0),
        J(16), J(18), J(20), J(17), J(19), J(21)]
MP = [head(0, 0, 0.10), head(0.015, 0.035, 0.09), head(0.03, 0.035, 0.085), head(0.045, 0.035, 0.075),
      head(-0.015, 0.035, 0.09), head(-0.03, 0.035, 0.085), head(-0.045, 0.035, 0.075),
      head(0.075, 0.02, 0), head(-0.075, 0.02, 0), head(0.025, -0.03, 0.09), head(-0.025, -0.03, 0.09),
      J(16), J(17), J(18), J(19), J(20), J(21),
      ("off", 20, (0.09, 0, -0.03)), ("off", 21, (-0.09, 0, -0.03)), ("off", 20, (0.09, 0, 0.03)),
      ("off", 21, (-0.09, 0, 0.03)), ("off", 20, (0.05, 0, 0.05)), ("off", 21, (-0.05, 0, 0.05)),
      J(1), J(2), J(4), J(5), J(7), J(8), ("off", 7, (0, -0.05, -0.05)), ("off", 8, (0, -0.05, -0.05)),
      ("off", 10, (0, 0, 0.04)), ("off", 11, (0, 0, 0.04))]
# Limb bones as (from, to) keypoint indices per layout.
BONES = {
    "h36m17": [(4, 5), (5, 6), (1, 2), (2, 3), (11, 12), (12, 13), (14, 15), (15, 16)],
    "mediapipe33": [(23, 25), (25, 27), (24, 26), (26, 28), (11, 13), (13, 15), (12, 14), (14, 16)],
}
# The same bones as SMPL joints (from, to).
SMPL_BONES = [(1, 4), (4, 7), (2, 5), (5, 8), (16, 18), (18, 20), (17, 19), (19, 21)]
PELVIS = {"h36m17": [0], "mediapipe33": [23, 24]}
PELVIS_SMPL = {"h36m17": [0], "mediapipe33": [1, 2]}  # the same point on the solved body

d = pickle.load(open(take, "rb"))
rot = d["smpl_poses"].reshape(-1, 24, 3).astype(np.float64)
trans = d["smpl_trans"].astype(np.float64) / float(np.asarray(d["smpl_scaling"]).reshape(-1)[0])
pos, glob = fk(rot, trans)
fails = 0
with tempfile.TemporaryDirectory() as tmp:
    for layout, markers in [("h36m17", H36M), ("mediapipe33", MP)]:
        npy = os.path.join(tmp, f"{layout}.npy")
        subprocess.run([exe, "footage", "synth", take, npy, "--clean", "--fps", "60", "--layout", layout,
                        "--units-per-metre", "1000"], check=True, capture_output=True)
        ours = np.load(npy).astype(np.float64)
        ref = np.zeros((pos.shape[0], len(markers), 3))
        for i, m in enumerate(markers):
            if m[0] == "joint":
                ref[:, i] = pos[:, m[1]]
            else:
                ref[:, i] = pos[:, m[1]] + glob[m[1]].apply(np.asarray(m[2], dtype=float))
        ref = ref * np.array([1.0, -1.0, -1.0]) * 1000.0  # camera axes (y down, z away), millimetres
        err = np.abs(ours - ref).max()
        ok = ours.shape == ref.shape and err < 0.05  # mm; float32 at ~2 m is ~0.0001 mm
        print(f"{layout}: keypoints {ours.shape}, max |choreo - numpy| {err:.5f} mm {'ok' if ok else 'FAIL'}")
        fails += not ok

        out = os.path.join(tmp, f"{layout}_solved.json")
        subprocess.run([exe, "convert", npy, out, "--keypoints", layout, "--source-fps", "60", "--smooth", "0"],
                       check=True, capture_output=True)
        s = json.load(open(out))
        srot = np.asarray(s["rotations"], dtype=float)
        strans = np.asarray(s["translation"], dtype=float)
        spos, _ = fk(srot, strans)
        kp = ours / 1000.0 * np.array([1.0, -1.0, -1.0])  # back to y up, metres
        worst = 0.0
        for (a, b), (sa, sb) in zip(BONES[layout], SMPL_BONES):
            u = kp[:, b] - kp[:, a]
            v = spos[:, sb] - spos[:, sa]
            cos = (u * v).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
            worst = max(worst, float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max()))
        root = np.abs(spos[:, PELVIS_SMPL[layout]].mean(1) - kp[:, PELVIS[layout]].mean(1)).max()
        ok = worst < 0.5 and root < 1e-4
        print(f"{layout}: solved limb bones within {worst:.4f} deg of the keypoints, pelvis point within {root * 1000:.4f} mm "
              f"{'ok' if ok else 'FAIL'}")
        fails += not ok

    # 3. A WHAM-style pickle written by Python's own pickle ({person id: {...}},
    # rotation matrices for global_orient / body_pose, camera axes, frames 3
    # and 7 undetected): choreo reads the longest person, bridges the missed
    # frames, and turns the camera frame (y down) to y up.
    T = 40
    ids = np.array([f for f in range(T) if f not in (3, 7)]) + 100
    rows = ids - 100
    flip = R.from_rotvec([np.pi, 0, 0])  # y up -> camera (y down, z away)
    go = (flip * R.from_rotvec(rot[rows, 0])).as_matrix().astype(np.float32)[:, None]
    bp = R.from_rotvec(rot[rows, 1:].reshape(-1, 3)).as_matrix().reshape(len(rows), 23, 3, 3).astype(np.float32)
    o0 = offsets[0]
    cam_trans = flip.apply(trans[rows] + o0) - o0
    wham = {7: {"global_orient": go, "body_pose": bp, "trans": cam_trans.astype(np.float32),
                "betas": np.zeros((len(rows), 10), np.float32), "frame_ids": ids},
            9: {"global_orient": go[:5], "body_pose": bp[:5], "trans": cam_trans[:5].astype(np.float32),
                "frame_ids": ids[:5]}}
    pkl = os.path.join(tmp, "wham_output.pkl")
    with open(pkl, "wb") as f:
        pickle.dump(wham, f, protocol=4)
    out = os.path.join(tmp, "wham.json")
    subprocess.run([exe, "convert", pkl, out, "--source-fps", "30"], check=True, capture_output=True)
    s = json.load(open(out))
    wrot = np.asarray(s["rotations"], dtype=float)
    wtrans = np.asarray(s["translation"], dtype=float)
    ok = wrot.shape == (T, 24, 3) and abs(s["fps"] - 30) < 1e-9
    kept = rows
    ang = (R.from_rotvec(wrot[kept].reshape(-1, 3)).inv() * R.from_rotvec(rot[kept].reshape(-1, 3))).magnitude()
    terr = np.abs(wtrans[kept] - trans[kept]).max()
    ok = ok and ang.max() < 1e-4 and terr < 1e-5
    print(f"WHAM pickle: {wrot.shape[0]} frames, max rotation error {np.degrees(ang.max()):.5f} deg, "
          f"translation {terr * 1000:.4f} mm on detected frames {'ok' if ok else 'FAIL'}")
    fails += not ok
sys.exit(1 if fails else 0)
