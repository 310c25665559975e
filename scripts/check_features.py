#!/usr/bin/env python3
"""choreo's window embeddings against scipy / numpy on the AIST++ samples.

- the window itself equals the pickle's smpl_poses (60 fps, channel-major);
- STFT magnitudes == |scipy.signal.stft(hann 16, hop 8, no padding)| * sum(window);
- DCT == scipy.fft.dct(type 2, norm='ortho')[:, :16];
- PCA fitted on every window (hop 32) of the 4 samples == numpy's covariance
  eigendecomposition: explained variance, components (up to sign), projection.

Usage: check_features.py PATH/TO/choreo DATA_DIR
"""
import json, os, pickle, subprocess, sys
import numpy as np
import scipy.fft, scipy.signal

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
