#!/usr/bin/env python3
"""A converted dance opens as a BVH that another tool reads: choreo writes BVH,
the independent `bvhio` package reads it and computes world joint positions,
which must match choreo's own forward kinematics of the source file.

Usage: check_bvh_bvhio.py PATH/TO/choreo DATA_DIR
"""
import json, os, subprocess, sys, tempfile
import numpy as np
import bvhio

exe, data = sys.argv[1], sys.argv[2]
cases = [(os.path.join(data, "aistpp/motions", f), []) for f in sorted(os.listdir(os.path.join(data, "aistpp/motions")))]
cases.append((os.path.join(data, "bandai/dataset-1/dataset-1_walk_happy_001.bvh"), ["--joints", "smpl13"]))
cases.append((os.path.join(data, "cmu/01_01.bvh"), ["--fps", "30"]))
fails = 0
with tempfile.TemporaryDirectory() as tmp:
    for src, extra in cases:
        out = os.path.join(tmp, "out.bvh")
        subprocess.run([exe, "convert", src, out] + extra, check=True, capture_output=True)
        ours = json.loads(subprocess.run([exe, "positions", out], check=True, capture_output=True, text=True).stdout)
        names, pos = ours["joints"], np.asarray(ours["positions"])  # metres
        if not extra:  # the BVH must also match FK of the original file
            direct = np.asarray(json.loads(subprocess.run([exe, "positions", src], check=True, capture_output=True, text=True).stdout)["positions"])
            dn = json.loads(subprocess.run([exe, "positions", src, "--frames", "0:1"], check=True, capture_output=True, text=True).stdout)["joints"]
            direct = direct[:, [dn.index(n) for n in names]]
            src_err = float(np.abs(direct - pos).max())
        else:
            src_err = 0.0
        bvh = bvhio.readAsBvh(out)
        hier = bvhio.readAsHierarchy(out)
        layout = list(hier.layout())
        frames = range(0, bvh.FrameCount, max(1, bvh.FrameCount // 40))
        err = 0.0
        for f in frames:
            hier.loadPose(f)
            for joint, _, _ in layout:
                p = np.array(joint.PositionWorld) / 100.0  # written in cm
                err = max(err, float(np.abs(p - pos[f, names.index(joint.Name)]).max()))
        ok = err < 2e-4 and src_err < 1e-6 and bvh.FrameCount == len(pos)
        fails += not ok
        print(f"{'ok' if ok else 'FAIL':4} {os.path.basename(src)} {' '.join(extra)}: {bvh.FrameCount} frames at "
              f"{1 / bvh.FrameTime:.2f} fps, {len(layout)} joints; bvhio vs choreo max {err * 1e3:.4f} mm, "
              f"BVH vs source FK max {src_err * 1e3:.6f} mm")
print("all BVH files read by bvhio agree" if not fails else f"{fails} FAILED")
sys.exit(1 if fails else 0)
