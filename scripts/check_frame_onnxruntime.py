#!/usr/bin/env python3
"""Check choreo's frame model runtime against onnxruntime.

Runs the exported global and local step graphs in onnxruntime with the
runtime's own bookkeeping written again here (fixed-capacity caches, the
mask over unused rows, positions, change codes) and compares every
teacher-forced logit with what choreo's tract runtime produced.
Usage: check_frame_onnxruntime.py MODEL_DIR DUMP.json
DUMP holds {"frames": [[slots]...], "cond": [vocab floats], "rel": [[...]], "abs": [[...]]}.
Exit 1 on any disagreement above 1e-4.
"""
import json, sys
import numpy as np
import onnxruntime as ort

model_dir, dump_path = sys.argv[1], sys.argv[2]
m = json.load(open(f"{model_dir}/manifest.json"))
c = m["config"]
dump = json.load(open(dump_path))
opts = ort.SessionOptions()
opts.intra_op_num_threads = 1
g = ort.InferenceSession(f"{model_dir}/{m['global_onnx']}", opts, providers=["CPUExecutionProvider"])
l = ort.InferenceSession(f"{model_dir}/{m['local_onnx']}", opts, providers=["CPUExecutionProvider"])
R, S = c["radius"], c["slots"]
ESC, NONE, START = 2 * R + 1, 2 * R + 2, 2 * R + 3


def change(a, b):
    if a is None:
        return NONE
    d = b - a
    return d + R if abs(d) <= R else ESC


class Cache:
    def __init__(self, layers, heads, cap, dh):
        self.k = [np.zeros((1, heads, cap, dh), np.float32) for _ in range(layers)]
        self.v = [np.zeros((1, heads, cap, dh), np.float32) for _ in range(layers)]
        self.cap, self.len = cap, 0

    def feeds(self):
        bias = np.full((1, self.cap + 1), -1e9, np.float32)
        bias[0, : self.len] = 0
        bias[0, self.cap] = 0
        f = {"bias": bias}
        for i in range(len(self.k)):
            f[f"cache_k_{i}"], f[f"cache_v_{i}"] = self.k[i], self.v[i]
        return f

    def push(self, out, names):
        for i in range(len(self.k)):
            self.k[i][:, :, self.len, :] = out[names.index(f"k_{i}")][:, :, 0, :]
            self.v[i][:, :, self.len, :] = out[names.index(f"v_{i}")][:, :, 0, :]
        self.len += 1


gnames = [o.name for o in g.get_outputs()]
lnames = [o.name for o in l.get_outputs()]
cond = np.asarray(dump["cond"], np.float32)[None]
gc = Cache(c["global_layers"], c["global_heads"], c["max_frames"] + 1, c["d_global"] // c["global_heads"])


def gstep(val, chg, is_cond):
    f = gc.feeds()
    f.update({"val": np.asarray([val], np.int64), "chg": np.asarray([chg], np.int64), "cond": cond,
              "is_cond": np.asarray([[is_cond]], np.float32), "pos": np.asarray([gc.len], np.int64)})
    out = g.run(None, f)
    gc.push(out, gnames)
    return out[0].reshape(1, -1)


frames = dump["frames"]
h = gstep([0] * S, [NONE] * S, 1.0)
worst = 0.0
for fi, frame in enumerate(frames):
    p1 = frames[fi - 1] if fi > 0 else None
    p2 = frames[fi - 2] if fi > 1 else None
    lc = Cache(c["local_layers"], c["local_heads"], S, c["d_local"] // c["local_heads"])
    rel, ab = [], []
    inp = START
    for s in range(S):
        vel = NONE if p1 is None or p2 is None else change(p2[s], p1[s])
        prev = c["bins"] if p1 is None else p1[s]
        f = lc.feeds()
        f.update({"ctx": h.astype(np.float32), "inp": np.asarray([inp], np.int64), "vel": np.asarray([vel], np.int64),
                  "prev": np.asarray([prev], np.int64), "slot": np.asarray([s], np.int64)})
        out = l.run(None, f)
        lc.push(out, lnames)
        rel.extend(out[0].reshape(-1).tolist())
        ab.extend(out[1].reshape(-1).tolist())
        inp = change(None if p1 is None else p1[s], frame[s])
    worst = max(worst, float(np.max(np.abs(np.asarray(rel) - np.asarray(dump["rel"][fi])))),
                float(np.max(np.abs(np.asarray(ab) - np.asarray(dump["abs"][fi])))))
    h = gstep(frame, [change(None if p1 is None else p1[s], frame[s]) for s in range(S)], 0.0)
print(json.dumps({"onnxruntime": ort.__version__, "frames": len(frames), "max_abs_diff": worst}))
sys.exit(0 if worst < 1e-4 else 1)
