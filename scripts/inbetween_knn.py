#!/usr/bin/env python3
"""How much of a dance's in-betweens its keyframes tell: motion matching.

For keyframes every SPACING frames on held-out AIST++-VRM dances, each
segment's in-betweens are rebuilt as SLERP plus the residual (each joint's
rotation relative to SLERP, in the joint's own frame; the root height
relative to a lerp) averaged over the K training segments whose four
keyframes (the two around the segment, weighted twice, and their
neighbours) look most alike. The pose at a keyframe is described by the
rotation matrices of the 23 joints below the root and the root's rotation
relative to the segment's first keyframe, so the match does not depend on
where the dancer faces. The error is the mean squared FK position error
(cm², summed over x, y, z; mean over the 24 joints and every frame of the
clip) against SLERP's on the same keyframes.

If the keyframes decided the in-betweens, the nearest segments of 136
other dances (the same basic choreographies danced by other dancers to
other music) would carry the right residual. Usage:

    CHOREO_DATA=../shared/data scripts/inbetween_knn.py [--spacing 30] [--held-out 15] [--seed 0] [--k 1,4,16]

Needs numpy and scipy. Takes about 4 minutes on one core.
"""
import argparse, os, sys
import numpy as np
from scipy.spatial.transform import Rotation as R, Slerp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import smpl_fk  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--spacing", type=int, default=30)
ap.add_argument("--held-out", type=int, default=15)
ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--k", default="1,4,16")
ap.add_argument("--stride", type=int, default=3, help="training segments start every STRIDE frames")
a = ap.parse_args()
S = a.spacing
data = os.environ.get("CHOREO_DATA", "../shared/data")
parents, offsets = smpl_fk.skeleton(data)
mdir = f"{data}/aistpp-vrm/motions"
files = sorted(os.listdir(mdir))
held = smpl_fk.held_out(len(files), a.held_out, a.seed)


def load(f):
    return smpl_fk.load(os.path.join(mdir, f))


def fk(q, tr):
    return smpl_fk.fk(q, tr, parents, offsets)


def slerp(qa, qb, n):
    """(n + 1, 24, 4): both keyframes and the n - 1 frames between."""
    t = np.arange(n + 1) / n
    return np.stack([Slerp([0, 1], R.from_quat([qa[j], qb[j]]))(t).as_quat() for j in range(24)], axis=1)


def relative(base, q):
    return (R.from_quat(base.reshape(-1, 4)).inv() * R.from_quat(q.reshape(-1, 4))).as_rotvec()


def features(q, k0, k1, kp, kn):
    r0 = R.from_quat(q[k0, 0])
    out = []
    for k in (kp, k0, k1, kn):
        joints = R.from_quat(q[k, 1:]).as_matrix().reshape(-1)
        root = (r0.inv() * R.from_quat(q[k, 0])).as_matrix().reshape(-1)
        out.append(np.concatenate([joints, 2 * root]) * (2.0 if k in (k0, k1) else 1.0))
    return np.concatenate(out)


clips = [load(f) for f in files]
X, Y = [], []
for i, (q, tr) in enumerate(clips):
    if i in held:
        continue
    for k0 in range(S, len(q) - 2 * S, a.stride):
        k1 = k0 + S
        X.append(features(q, k0, k1, k0 - S, k1 + S))
        lerp_y = np.linspace(tr[k0, 1], tr[k1, 1], S + 1)[1:S]
        Y.append(np.concatenate([relative(slerp(q[k0], q[k1], S)[1:S], q[k0 + 1 : k1]).reshape(-1), tr[k0 + 1 : k1, 1] - lerp_y]))
X, Y = np.asarray(X, np.float32), np.asarray(Y)
print(f"{len(X)} training segments of {S} frames from {len(clips) - len(held)} dances; {len(held)} held out")


def matched(x, k):
    d = ((X - x[None]) ** 2).sum(1)
    idx = np.argpartition(d, k)[:k]
    w = 1 / (d[idx] + 1e-3)
    return (Y[idx] * (w / w.sum())[:, None]).sum(0)


for k in [int(v) for v in a.k.split(",")]:
    err_slerp = err_knn = 0.0
    for i in sorted(held):
        q, tr = clips[i]
        n = len(q)
        keys = smpl_fk.keyframes(n, S)
        qs, ts = q.copy(), tr.copy()
        qk, tk = q.copy(), tr.copy()
        for j, (k0, k1) in enumerate(zip(keys[:-1], keys[1:])):
            L = k1 - k0
            if L < 2:
                continue
            base = slerp(q[k0], q[k1], L)[1:L]
            qs[k0 + 1 : k1] = qk[k0 + 1 : k1] = base
            ts[k0 + 1 : k1] = tk[k0 + 1 : k1] = np.linspace(tr[k0], tr[k1], L + 1)[1:L]
            if L == S:
                y = matched(features(q, k0, k1, keys[max(0, j - 1)], keys[min(len(keys) - 1, j + 2)]), k)
                rv = y[: (S - 1) * 72].reshape(-1, 3)
                qk[k0 + 1 : k1] = (R.from_quat(base.reshape(-1, 4)) * R.from_rotvec(rv)).as_quat().reshape(S - 1, 24, 4)
                tk[k0 + 1 : k1, 1] += y[(S - 1) * 72 :]
        real = fk(q, tr)
        err_slerp += ((fk(qs, ts) - real) ** 2).sum(-1).mean() * 1e4
        err_knn += ((fk(qk, tk) - real) ** 2).sum(-1).mean() * 1e4
    m = len(held)
    print(f"K {k:3}: SLERP {err_slerp / m:.2f} cm², matched {err_knn / m:.2f} cm² ({err_knn / err_slerp:.3f}× SLERP)")
