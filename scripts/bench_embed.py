#!/usr/bin/env python3
"""Embedding throughput of scipy/numpy on the windows `choreo bench embed --dump
DIR` wrote (the same windows choreo timed): STFT magnitudes, DCT-II (16
coefficients), PCA fit + projection. Vectorised over all windows at once, which
is numpy's best case.

Usage: bench_embed.py DIR
"""
import json, sys, time
import numpy as np
import scipy.fft, scipy.signal

w = np.load(f"{sys.argv[1]}/windows.npy").astype(np.float32).reshape(-1, 72, 128)
n = len(w)
win = scipy.signal.get_window("hann", 16)
out = {}
t = time.perf_counter()
_, _, Z = scipy.signal.stft(w, window=win, nperseg=16, noverlap=8, boundary=None, padded=False, detrend=False, axis=-1)
stft = np.abs(Z) * win.sum()
out["stft"] = {"windows_per_s": n / (time.perf_counter() - t)}
t = time.perf_counter()
dct = scipy.fft.dct(w, type=2, norm="ortho", axis=-1)[..., :16]
out["dct"] = {"windows_per_s": n / (time.perf_counter() - t)}
t = time.perf_counter()
S = w.reshape(-1, 128).astype(np.float64)
mean = S.mean(0)
vals, vecs = np.linalg.eigh(np.cov(S, rowvar=False))
comps = vecs[:, np.argsort(vals)[::-1][:16]]
fit = time.perf_counter() - t
t = time.perf_counter()
proj = (w - mean.astype(np.float32)) @ comps.astype(np.float32)
out["pca"] = {"fit_s": fit, "windows_per_s": n / (time.perf_counter() - t)}
print(json.dumps({"windows": n, "numpy": np.__version__, "scipy": scipy.__version__, "results": out}))
