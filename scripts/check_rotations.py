#!/usr/bin/env python3
"""Check choreo's rotation conversions against scipy.spatial.transform.Rotation.

Random rotations (fixed seed) go to `choreo dev rotations`; every conversion it
prints is compared with scipy's. Exit 1 on any disagreement.
Usage: check_rotations.py PATH/TO/choreo
"""
import json, subprocess, sys, warnings
warnings.filterwarnings('ignore', message='Gimbal lock')
import numpy as np
from scipy.spatial.transform import Rotation as R

exe = sys.argv[1]
rng = np.random.default_rng(7)
n = 2000
q_xyzw = R.random(n, random_state=11).as_quat()
# Also edge cases: identity, half turns, gimbal lock for XYZ and ZXY.
edge = [R.identity(), R.from_rotvec([np.pi, 0, 0]), R.from_rotvec([0, np.pi, 0]),
        R.from_rotvec([0, 0, np.pi]), R.from_rotvec([1e-9, 0, 0]),
        R.from_euler("XYZ", [0.3, np.pi / 2, 0.2]), R.from_euler("ZXY", [0.3, -np.pi / 2, 0.2])]
q_xyzw = np.vstack([q_xyzw] + [e.as_quat()[None] for e in edge])
wxyz = np.roll(q_xyzw, 1, axis=1)
orders = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "xyz", "xzy", "yxz", "yzx", "zxy", "zyx"]
out = json.loads(subprocess.run([exe, "dev", "rotations"], input=json.dumps({"quats": wxyz.tolist(), "orders": orders}),
                                capture_output=True, text=True, check=True).stdout)
rot = R.from_quat(q_xyzw)
fails = []

def check(name, got, want, tol):
    err = float(np.max(np.abs(np.asarray(got) - np.asarray(want))))
    status = "ok" if err <= tol else "FAIL"
    print(f"{status:4} {name:28} max abs err {err:.2e} (tol {tol:.0e})")
    if err > tol:
        fails.append(name)

def same_rotation(name, got_wxyz, tol):
    g = R.from_quat(np.roll(np.asarray(got_wxyz), -1, axis=1))
    ang = (g * rot.inv()).magnitude()
    check(name, ang, np.zeros_like(ang), tol)

check("matrix", out["matrix"], rot.as_matrix(), 1e-12)
check("axis_angle", out["axis_angle"], rot.as_rotvec(), 1e-9)
same_rotation("quat_from_axis_angle", out["quat_from_axis_angle"], 1e-7)
same_rotation("quat_from_matrix", out["quat_from_matrix"], 1e-7)
m6 = np.asarray(out["sixd"])
check("sixd", m6, np.concatenate([rot.as_matrix()[:, :, 0], rot.as_matrix()[:, :, 1]], axis=1), 1e-12)
check("matrix_from_sixd", out["matrix_from_sixd"], rot.as_matrix(), 1e-12)
for o in orders:
    want = rot.as_euler(o)
    got = np.asarray(out["euler"][o])
    # Away from gimbal lock the angles are unique; compare them directly there.
    mid = np.abs(np.abs(want[:, 1]) - np.pi / 2) > 1e-3
    d = (got[mid] - want[mid] + np.pi) % (2 * np.pi) - np.pi  # pi and -pi are one angle
    check(f"euler {o} angles", d, np.zeros_like(d), 1e-9)
    same_rotation(f"euler {o} round trip", out["quat_from_euler"][o], 1e-7)
    # scipy's euler -> rotation equals ours.
    ours = R.from_quat(np.roll(np.asarray(out["quat_from_euler"][o]), -1, axis=1))
    ref = R.from_euler(o, got)
    check(f"from_euler {o}", (ours * ref.inv()).magnitude(), np.zeros(len(got)), 1e-7)
geo = (rot[1:] * rot[:-1].inv()).magnitude()
check("geodesic angle", out["geodesic_next"], geo, 1e-9)
print(f"{n + len(edge)} rotations, {len(orders)} Euler orders: " + ("all agree with scipy" if not fails else f"FAILED: {fails}"))
sys.exit(1 if fails else 0)
