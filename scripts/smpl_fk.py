"""Shared by the in-betweener probes (inbetween_knn.py, inbetween_rhythm.py):
their held-out split and keyframes, an AIST++ pickle's rotations as
quaternions, and forward kinematics on the neutral SMPL skeleton that choreo
uses (data/smpl/skeleton_neutral.json)."""
import json, pickle
import numpy as np
from scipy.spatial.transform import Rotation as R


def skeleton(data):
    sk = json.load(open(f"{data}/smpl/skeleton_neutral.json"))
    return sk["parents"], np.asarray(sk["offsets"])


def load(path):
    """(frames, 24, 4) quaternions (x, y, z, w) and (frames, 3) root translation."""
    p = pickle.load(open(path, "rb"))
    rv = p["smpl_poses"].astype(np.float64).reshape(-1, 3)
    return R.from_rotvec(rv).as_quat().reshape(-1, 24, 4), p["smpl_trans"].astype(np.float64)


def fk(q, tr, parents, offsets):
    """Joint positions (frames, 24, 3) in metres."""
    pos, glob = np.zeros((len(q), 24, 3)), [None] * 24
    for j in range(24):
        local = R.from_quat(q[:, j])
        if parents[j] < 0:
            glob[j], pos[:, j] = local, tr
        else:
            glob[j] = glob[parents[j]] * local
            pos[:, j] = pos[:, parents[j]] + glob[parents[j]].apply(offsets[j])
    return pos


def held_out(count, n, seed):
    """The probes' held-out dances: n of the sorted files' indices."""
    return set(np.random.default_rng(seed).permutation(count)[:n])


def keyframes(frames, spacing):
    """Every spacing-th frame, and the first and last."""
    return sorted(set([0] + list(range(spacing, frames - 1, spacing)) + [frames - 1]))
