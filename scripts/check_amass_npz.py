#!/usr/bin/env python3
"""AMASS .npz in and out, checked with numpy/scipy.

1. numpy writes an AMASS-style npz (z up, SMPL-H 156-wide poses) from an AIST++
   pickle; choreo's FK of it must equal Rx(-90deg) applied to choreo's FK of the
   pickle (AMASS z-up -> choreo y-up) for the 22 body joints.
2. choreo writes an npz; numpy reads it back with the right keys and shapes.

Usage: check_amass_npz.py PATH/TO/choreo DATA_DIR
"""
import json, os, pickle, subprocess, sys, tempfile
import numpy as np
from scipy.spatial.transform import Rotation as R

exe, data = sys.argv[1], sys.argv[2]
src = os.path.join(data, "aistpp/motions/gJS_sBM_cAll_d03_mJS2_ch07.pkl")
with open(src, "rb") as f:
    d = pickle.load(f)
poses = np.zeros((len(d["smpl_poses"]), 156))
poses[:, :66] = d["smpl_poses"][:, :66]
trans = d["smpl_trans"] / d["smpl_scaling"]

def fk(path, frames="0:600"):
    out = json.loads(subprocess.run([exe, "positions", path, "--frames", frames], check=True, capture_output=True, text=True).stdout)
    return np.asarray(out["positions"])

fails = 0
with tempfile.TemporaryDirectory() as tmp:
    # AIST++ is y up; express the same world z up as AMASS does: p_z = Rx(+90) p_y.
    up = R.from_euler("x", 90, degrees=True)
    root = up * R.from_rotvec(poses[:, :3])
    pelvis_rest = np.array([-0.0017950618639588356, -0.2233334481716156, 0.028219128027558327])
    z_poses = poses.copy()
    z_poses[:, :3] = root.as_rotvec()
    z_trans = up.apply(pelvis_rest + trans) - pelvis_rest
    npz = os.path.join(tmp, "amass_like.npz")
    np.savez_compressed(npz, poses=z_poses, trans=z_trans, mocap_framerate=np.array(60.0), betas=np.zeros(16), gender="neutral")
    info = json.loads(subprocess.run([exe, "inspect", npz, "--json"], check=True, capture_output=True, text=True).stdout)
    a = fk(npz)[:, :22]
    b = fk(src)[:, :22]
    err = float(np.abs(a - b).max())
    ok = err < 1e-6 and info["format"] == "amass" and info["fps"] == 60.0 and info["frames"] == len(poses)
    fails += not ok
    print(f"{'ok' if ok else 'FAIL':4} numpy-written AMASS npz (z up) read by choreo: {info['frames']} frames at {info['fps']} fps; "
          f"FK vs the pickle's, max {err:.2e} m")
    out = os.path.join(tmp, "choreo.npz")
    subprocess.run([exe, "convert", src, out], check=True, capture_output=True)
    z = np.load(out)
    ok2 = z["poses"].shape == (len(poses), 156) and z["trans"].shape == (len(poses), 3) and float(z["mocap_framerate"]) == 60.0
    # choreo's npz should be (up to float rounding) the same arrays we built by hand.
    e2 = max(float(np.abs(R.from_rotvec(z["poses"][:, :3]).as_matrix() - root.as_matrix()).max()), float(np.abs(z["trans"] - z_trans).max()),
             float(np.abs(z["poses"][:, 3:66] - poses[:, 3:66]).max()))
    ok2 = ok2 and e2 < 1e-6
    fails += not ok2
    print(f"{'ok' if ok2 else 'FAIL':4} choreo-written npz read by numpy: keys {sorted(z.files)}, poses {z['poses'].shape}; max diff from hand-built {e2:.2e}")
print("AMASS npz checks pass" if not fails else f"{fails} FAILED")
sys.exit(1 if fails else 0)
