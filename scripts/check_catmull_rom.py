#!/usr/bin/env python3
"""Check choreo's Catmull-Rom in-betweens against scipy's CubicHermiteSpline.

The spline through the keyframes, with each keyframe's tangent the slope
between its neighbours (one-sided at the ends), is built with scipy from the
keyframes alone and compared with `choreo dev catmull-rom` on (a) a real
AIST++ dance's joint angles and root path with uneven keyframes and (b)
random channels. Exit 1 on any disagreement.
Usage: check_catmull_rom.py PATH/TO/choreo DATA_ROOT
"""
import glob, json, os, pickle, subprocess, sys
import numpy as np
from scipy.interpolate import CubicHermiteSpline

exe, root = sys.argv[1], sys.argv[2]
fails = []


def reference(values, keys):
    k = np.asarray(keys, dtype=float)
    y = values[keys]
    lo = np.r_[0, np.arange(len(keys) - 1)]
    hi = np.r_[np.arange(1, len(keys)), len(keys) - 1]
    dydx = (y[hi] - y[lo]) / (k[hi] - k[lo])[:, None]
    return CubicHermiteSpline(k, y, dydx, axis=0)(np.arange(len(values)))


def check(name, values, keys, tol=1e-9):
    out = subprocess.run([exe, "dev", "catmull-rom"],
                         input=json.dumps({"values": values.tolist(), "keys": keys}),
                         capture_output=True, text=True, check=True).stdout
    got = np.asarray(json.loads(out)["values"])
    want = reference(values, keys)
    err = float(np.max(np.abs(got - want)))
    kept = float(np.max(np.abs(got[keys] - values[keys])))
    status = "ok" if err <= tol and kept == 0.0 else "FAIL"
    print(f"{status:4} {name:40} max abs err {err:.2e} (tol {tol:.0e}); keyframes moved {kept:.1e}")
    if status != "ok":
        fails.append(name)


files = sorted(glob.glob(os.path.join(root, "aistpp", "motions", "*.pkl")))
if not files:
    sys.exit(f"no AIST++ pickles under {root}/aistpp/motions")
with open(files[0], "rb") as f:
    d = pickle.load(f, encoding="latin1")
poses = np.asarray(d["smpl_poses"], dtype=float)[:600]
trans = np.asarray(d["smpl_trans"], dtype=float)[:600] / float(np.ravel(d.get("smpl_scaling", [1.0]))[0])
real = np.hstack([poses, trans])
n = len(real)
rng = np.random.default_rng(3)
even = list(range(0, n - 1, 30)) + [n - 1]
uneven = sorted({0, n - 1, *rng.choice(np.arange(1, n - 1), size=25, replace=False).tolist()})
check(f"{os.path.basename(files[0])} every 30", real, even)
check(f"{os.path.basename(files[0])} 27 uneven keys", real, uneven)
check("random, 2 keys (a line)", rng.normal(size=(40, 5)), [0, 39])
check("random, adjacent keys", rng.normal(size=(12, 3)), [0, 1, 2, 5, 11])
if fails:
    sys.exit(f"{len(fails)} checks failed: {fails}")
