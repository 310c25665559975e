#!/usr/bin/env python3
"""Do a dance's repeats or its music's beat tell the in-betweens?

Two model-free probes for #15's in-betweener goal on AIST++-VRM (30-frame
keyframe spacing at 60 fps; docs/RESULTS.md, "Session 30: repeats and
beats"):

1. Repeats. For each held-out dance (the split of scripts/inbetween_knn.py:
   seed 0, 15 dances), the shift tau >= 60 frames at which the dance is most
   like itself (root-relative joint positions, the mean over every frame
   pair t, t + tau), beside SLERP's error on keyframes every 30 frames. If a
   dance repeated closely, the keyframes of one repeat would sample the
   in-betweens of another. Both errors in cm² (sum over x, y, z; mean over
   the 24 joints and frames), as scripts/inbetween_knn.py.
2. Beats. Each dance's joint angular speed folded by its music's beat (the
   tempo from the music id in the name), in 12 phase bins, as a share of
   its mean: if dancers moved at the same point of every beat, the mean
   profile over dances would not be flat, and a known tempo would say when
   in a gap the limbs move.
3. Timing. SLERP along each joint's geodesic, but paced by a speed profile
   instead of evenly: the dance's beat profile from probe 2 (an oracle: it
   is measured on the dance itself), or the true angular speed of every
   frame (an oracle that knows exactly when the body moves). What is left
   is the path's shape, which no timing can fix.

    CHOREO_DATA=../shared/data scripts/inbetween_rhythm.py

Needs numpy and scipy; about 12 seconds.
"""
import os, sys
import numpy as np
from scipy.spatial.transform import Rotation as R, Slerp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import smpl_fk  # noqa: E402

data = os.environ.get("CHOREO_DATA", "../shared/data")
parents, offsets = smpl_fk.skeleton(data)
mdir = f"{data}/aistpp-vrm/motions"
files = sorted(os.listdir(mdir))
held = smpl_fk.held_out(len(files), 15, 0)
S, BINS = 30, 12


def load(f):
    return smpl_fk.load(os.path.join(mdir, f))


def fk(q, tr):
    return smpl_fk.fk(q, tr, parents, offsets)


def paced(q, tr, keys, pace):
    """SLERP between the keys, each gap's progress the running sum of
    pace(k0, k1) (a weight per frame k0..k1-1; even pacing = plain SLERP)."""
    qs, ts = q.copy(), tr.copy()
    for k0, k1 in zip(keys[:-1], keys[1:]):
        L = k1 - k0
        if L < 2:
            continue
        c = np.cumsum(pace(k0, k1))
        u = c[:-1] / c[-1]
        for j in range(24):
            qs[k0 + 1 : k1, j] = Slerp([0, 1], R.from_quat([q[k0, j], q[k1, j]]))(u).as_quat()
        ts[k0 + 1 : k1] = tr[k0] + (tr[k1] - tr[k0]) * u[:, None]
    return qs, ts


def angular_speed(q):
    d = np.abs((q[1:] * q[:-1]).sum(-1)).clip(0, 1)
    return (2 * np.arccos(d)).sum(-1)


def beat_profile(speed, tempo):
    phase = ((np.arange(len(speed)) + 0.5) * tempo / 3600) % 1
    h = np.array([speed[(phase >= b / BINS) & (phase < (b + 1) / BINS)].mean() for b in range(BINS)])
    return h / h.mean()


def bpm(name):
    """The music id's tempo, as src/motion/labels.rs `aist_tempo_bpm` reads it."""
    m = name.split("_")[4]
    return 110 + 5 * int(m[3]) if m[1:3] == "HO" else 80 + 10 * int(m[3])


# The held-out dances once: probe 1's repeat, and probe 3's three pacings
# (the first of which, even, is plain SLERP).
rows = []
for i in sorted(held):
    f = files[i]
    q, tr = load(f)
    n, pos = len(q), fk(q, tr)
    rel = pos - pos[:, :1]
    keys = smpl_fk.keyframes(n, S)
    speed, tempo = angular_speed(q), bpm(f)
    h = beat_profile(speed, tempo)
    paces = [
        lambda k0, k1: np.ones(k1 - k0),
        lambda k0, k1: h[(((np.arange(k0, k1) + 0.5) * tempo / 3600) % 1 * BINS).astype(int)],
        lambda k0, k1: speed[k0:k1] + 1e-9,
    ]
    errs = [((fk(*paced(q, tr, keys, p)) - pos) ** 2).sum(-1).mean() * 1e4 for p in paces]
    shifts = [(((rel[t:] - rel[:-t]) ** 2).sum(-1).mean() * 1e4, t) for t in range(60, n // 2)]
    rows.append((f[:-4], tempo, errs, *min(shifts)))

print("1. repeats (held out):")
for name, tempo, errs, e_rep, tau in rows:
    print(f"  {name:30} SLERP {errs[0]:6.1f}  nearest repeat {e_rep:6.1f} at {tau} frames ({tau * tempo / 3600:.2f} beats)")
m_slerp, m_rep = np.mean([r[2][0] for r in rows]), np.mean([r[3] for r in rows])
print(f"  mean: SLERP {m_slerp:.1f}, nearest repeat {m_rep:.1f} cm²")

print("2. beats (all 151 dances): angular speed by beat phase, share of the dance's mean")
prof = []
for f in files:
    q, _ = load(f)
    prof.append(beat_profile(angular_speed(q), bpm(f)))
prof = np.array(prof)
print("  mean over dances:", " ".join(f"{v:.2f}" for v in prof.mean(0)))
print("  sd over dances:  ", " ".join(f"{v:.2f}" for v in prof.std(0)))
print("  per dance, largest / smallest bin: median", f"{np.median(prof.max(1) / prof.min(1)):.2f}")

print("3. timing (held out): SLERP paced by the dance's beat profile, and by the true speed")
for name, _, errs, _, _ in rows:
    print(f"  {name:30} even {errs[0]:6.1f}  beat profile {errs[1]:6.1f}  true speed {errs[2]:6.1f}")
m = np.mean([r[2] for r in rows], axis=0)
print(f"  mean: even (SLERP) {m[0]:.1f}, beat profile {m[1]:.1f} ({m[1] / m[0] - 1:+.1%}), true speed {m[2]:.1f} ({m[2] / m[0] - 1:+.1%}) cm²")
