#!/usr/bin/env python3
"""Step latencies of an exported choreo frame model in onnxruntime (one
intra-op thread), the Python side of `choreo bench model` for
`motion-frame-lm` models: a global step with 150 frames cached and a local
(slot) step at the middle slot, the same inputs choreo times, plus the
global pass over a whole context window (classification's forward).

Usage: python3 scripts/bench_frame_onnxruntime.py MODEL_DIR [REPEATS]
Prints one JSON line.
"""
import json
import sys
import time

import numpy as np
import onnxruntime as ort

model_dir = sys.argv[1]
repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
m = json.load(open(f"{model_dir}/manifest.json"))
c = m["config"]
so = ort.SessionOptions()
so.intra_op_num_threads = 1
so.inter_op_num_threads = 1
g = ort.InferenceSession(f"{model_dir}/{m['global_onnx']}", so, providers=["CPUExecutionProvider"])
loc = ort.InferenceSession(f"{model_dir}/{m['local_onnx']}", so, providers=["CPUExecutionProvider"])
S, R, bins = c["slots"], c["radius"], c["bins"]
gcap = c["max_frames"] + 1


def caches(layers, heads, cap, dh):
    return {
        **{f"cache_k_{i}": np.zeros((1, heads, cap, dh), np.float32) for i in range(layers)},
        **{f"cache_v_{i}": np.zeros((1, heads, cap, dh), np.float32) for i in range(layers)},
    }


def bias(cap, filled):
    b = np.full((1, cap + 1), -1e9, np.float32)
    b[0, :filled] = 0
    b[0, cap] = 0
    return b


cond = np.zeros((1, c["vocab_size"]), np.float32)
cond[0, 0] = 1.0
mid = np.full((1, S), bins // 2, np.int64)
gfeed = {
    "val": mid,
    "chg": np.full((1, S), R, np.int64),
    "cond": cond,
    "is_cond": np.zeros((1, 1), np.float32),
    "pos": np.asarray([150], np.int64),
    "bias": bias(gcap, 150),
    **caches(c["global_layers"], c["global_heads"], gcap, c["d_global"] // c["global_heads"]),
}
lfeed = {
    "ctx": np.zeros((1, c["d_global"]), np.float32),
    "inp": np.asarray([R], np.int64),
    "vel": np.asarray([R], np.int64),
    "prev": np.asarray([0], np.int64),
    "slot": np.asarray([S // 2], np.int64),
    "bias": bias(S, S // 2),
    **caches(c["local_layers"], c["local_heads"], S, c["d_local"] // c["local_heads"]),
}


def p50(run, n):
    run()
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        run()
        ts.append((time.perf_counter() - t) * 1e3)
    ts.sort()
    return ts[len(ts) // 2]


gstep = p50(lambda: g.run(None, gfeed), repeats)
lstep = p50(lambda: loc.run(None, lfeed), repeats)
# The whole-window global pass: max_frames steps, each writing its cache row.
gn = [o.name for o in g.get_outputs()]


def window():
    f = dict(gfeed)
    for k in list(f):
        if k.startswith("cache_"):
            f[k] = np.zeros_like(f[k])
    for t in range(c["max_frames"]):
        f["pos"] = np.asarray([t], np.int64)
        f["bias"] = bias(gcap, t)
        out = g.run(None, f)
        for i in range(c["global_layers"]):
            f[f"cache_k_{i}"][:, :, t, :] = out[gn.index(f"k_{i}")][:, :, 0, :]
            f[f"cache_v_{i}"][:, :, t, :] = out[gn.index(f"v_{i}")][:, :, 0, :]


t0 = time.perf_counter()
reps = 3
for _ in range(reps):
    window()
win = (time.perf_counter() - t0) / reps * 1e3
print(json.dumps({
    "runtime": "python-onnxruntime",
    "onnxruntime": ort.__version__,
    "global_step_ms_p50": gstep,
    "local_step_ms_p50": lstep,
    "decode_step_ms_p50": lstep,
    "frame_ms_estimate": gstep + S * lstep,
    "window_frames": c["max_frames"],
    "window_forward_ms": win,
}))
