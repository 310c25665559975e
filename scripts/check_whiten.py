"""Sequence whitening (src/features/whiten.rs) against scipy's generalised
symmetric eigensolver: the directions maximising pᵀSb p / pᵀSw p, with Sw
shrunk as choreo does, normalised pᵀSw p = 1 (scipy.linalg.eigh(Sb, Sw)
returns them so). Usage: check_whiten.py CHOREO_BINARY"""
import json
import subprocess
import sys

import numpy as np
from scipy.linalg import eigh

choreo = sys.argv[1]
rng = np.random.default_rng(7)
d, sequences, per, k, shrink = 12, 9, 15, 5, 0.01
centres = rng.normal(size=(sequences, d)) * np.linspace(2.0, 0.1, d)
spread = rng.normal(size=(d, d)) * 0.3
x, seq = [], []
for s in range(sequences):
    for _ in range(per):
        x.append(centres[s] + rng.normal(size=d) @ spread)
        seq.append(s)
x = np.asarray(x, dtype=np.float32)
seq = np.asarray(seq)

out = subprocess.run(
    [choreo, "dev", "whiten", "--k", str(k), "--shrink", str(shrink)],
    input=json.dumps({"vectors": x.tolist(), "sequence": seq.tolist()}),
    capture_output=True, text=True, check=True)
got = json.loads(out.stdout)

xf = x.astype(np.float64)
n = len(xf)
mu = xf.mean(0)
sw = np.zeros((d, d))
sb = np.zeros((d, d))
for s in range(sequences):
    z = xf[seq == s]
    m = z.mean(0)
    sw += (z - m).T @ (z - m) / n
    sb += len(z) / n * np.outer(m - mu, m - mu)
sw = (1 - shrink) * sw + shrink * np.trace(sw) / d * np.eye(d)
vals, vecs = eigh(sb, sw)
order = np.argsort(vals)[::-1][:k]
want_ratios = vals[order]
want_dirs = vecs[:, order].T

ratios = np.asarray(got["ratios"])
dirs = np.asarray(got["directions"])
assert np.allclose(np.asarray(got["mean"]), mu, atol=1e-9), "mean"
assert ratios.shape == (k,), ratios.shape
assert np.allclose(ratios, want_ratios, rtol=1e-8, atol=1e-10), (ratios, want_ratios)
worst = 0.0
for p, q in zip(dirs, want_dirs):
    sign = 1.0 if p @ q >= 0 else -1.0
    worst = max(worst, float(np.abs(p - sign * q).max() / np.abs(q).max()))
    assert abs(p @ sw @ p - 1.0) < 1e-8, "pᵀ Sw p = 1"
assert worst < 1e-6, worst
print(f"whitening: {k} directions of {d}-d over {sequences} sequences; ratios {np.round(ratios, 4).tolist()} "
      f"equal scipy's to rtol 1e-8; directions to {worst:.1e} (relative)")
