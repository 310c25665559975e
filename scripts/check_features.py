#!/usr/bin/env python3
"""choreo's window embeddings against scipy / numpy on the AIST++ samples.

- the window itself equals the pickle's smpl_poses (60 fps, channel-major);
- STFT magnitudes == |scipy.signal.stft(hann 16, hop 8, no padding)| * sum(window);
- DCT == scipy.fft.dct(type 2, norm='ortho')[:, :16];
- pose == scipy forward kinematics of the window on the SMPL neutral body:
  13 joints relative to the pelvis, turned about y so that the pelvis faces
  +z at frame 64, then DCT-II ortho, first 16 per coordinate;
- PCA fitted on every window (hop 32) of the 4 samples == numpy's covariance
  eigendecomposition: explained variance, components (up to sign), projection.

Usage: check_features.py PATH/TO/choreo DATA_DIR
"""
import json, os, pickle, subprocess, sys
import numpy as np
import scipy.fft, scipy.signal
from scipy.spatial.transform import Rotation as R

exe, data = sys.argv[1], sys.argv[2]
mdir = os.path.join(data, "aistpp/motions")
files = sorted(os.path.join(mdir, f) for f in os.listdir(mdir))
target, start = files[3], 192
out = json.loads(subprocess.run([exe, "dev", "features", "--motion", target, "--start", str(start)] + sum([["--pca-on", f] for f in files], []),
                                check=True, capture_output=True, text=True).stdout)
fails = []

def check(name, got, want, tol, rel=False):
    got, want = np.asarray(got, float), np.asarray(want, float)
    err = np.abs(got - want).max() / (np.abs(want).max() if rel else 1.0)
    ok = err <= tol
    print(f"{'ok' if ok else 'FAIL':4} {name:34} max {'rel ' if rel else ''}err {err:.2e} (tol {tol:.0e})")
    if not ok:
        fails.append(name)

poses = lambda f: pickle.load(open(f, "rb"))["smpl_poses"].astype(np.float64)
x = poses(target)[start:start + 128].T  # (72, 128)
check("window == smpl_poses slice", np.asarray(out["window"]).reshape(72, 128), x, 1e-7)
win = scipy.signal.get_window("hann", 16)
_, _, Z = scipy.signal.stft(x, window=win, nperseg=16, noverlap=8, boundary=None, padded=False, detrend=False, return_onesided=True)
ref_stft = np.abs(Z) * win.sum()  # (72, 9 bins, 15 frames)
check("STFT magnitudes", np.asarray(out["stft"]).reshape(72, 15, 9), ref_stft.transpose(0, 2, 1), 1e-4, rel=True)
ref_dct = scipy.fft.dct(x, type=2, norm="ortho", axis=-1)
check("DCT-II ortho, first 16", np.asarray(out["dct"]).reshape(72, 16), ref_dct[:, :16], 1e-4, rel=True)
check("DCT-II ortho, all 128", np.asarray(out["dct_full"]).reshape(72, 128), ref_dct, 1e-4, rel=True)

sk = json.load(open(os.path.join(data, "smpl/skeleton_neutral.json")))
parents, offsets = sk["parents"], np.asarray(sk["offsets"])
rots = x.T.reshape(128, 24, 3)
pos, glob = np.zeros((128, 24, 3)), [None] * 24
for j in range(24):
    local = R.from_rotvec(rots[:, j])
    if parents[j] < 0:
        glob[j] = local
    else:
        glob[j] = glob[parents[j]] * local
        pos[:, j] = pos[:, parents[j]] + glob[parents[j]].apply(offsets[j])
fwd = glob[0][64].apply([0, 0, 1])
unturn = R.from_rotvec([0, -np.arctan2(fwd[0], fwd[2]), 0])
joints = [1, 2, 4, 5, 7, 8, 16, 17, 18, 19, 20, 21, 15]
rel = unturn.apply(pos[:, joints].reshape(-1, 3)).reshape(128, len(joints) * 3).T  # (39, 128)
ref_pose = scipy.fft.dct(rel, type=2, norm="ortho", axis=-1)[:, :16]
check("pose (FK, heading, DCT-II first 16)", np.asarray(out["pose"]).reshape(39, 16), ref_pose, 1e-4, rel=True)

series = []
for f in files:
    p = poses(f)
    for s in range(0, len(p) - 128 + 1, 32):
        series.append(p[s:s + 128].T)
S = np.concatenate(series)  # (windows*72, 128)
mean = S.mean(0)
vals, vecs = np.linalg.eigh(np.cov(S, rowvar=False))
order = np.argsort(vals)[::-1][:16]
vals, vecs = vals[order], vecs[:, order]
pca = out["pca"]
check("PCA mean", pca["mean"], mean, 1e-5)
check("PCA explained variance", pca["explained_variance"], vals, 1e-4, rel=True)
comps = np.asarray(pca["components"]).reshape(16, 128)
cos = np.abs((comps * vecs.T).sum(1))
check("PCA components |cos| with numpy", cos, np.ones(16), 1e-3)
signs = np.sign((comps * vecs.T).sum(1))
proj = (x - mean) @ vecs * signs
check("PCA projection", np.asarray(pca["projection"]).reshape(72, 16), proj, 1e-3, rel=True)
print(f"{len(series)} windows: " + ("all agree with scipy/numpy" if not fails else f"FAILED {fails}"))
sys.exit(1 if fails else 0)
