#!/usr/bin/env python3
"""Check choreo's frame model runtime against onnxruntime.

Runs the exported global and local step graphs in onnxruntime with the
runtime's own bookkeeping written again here (fixed-capacity caches, the
mask over unused rows, positions, change codes) and compares every
teacher-forced logit with what choreo's tract runtime produced.
Usage: check_frame_onnxruntime.py MODEL_DIR DUMP.json
DUMP holds {"frames": [[slots]...], "cond": [vocab floats], "rel": [[...]], "abs": [[...]]}
and, optionally, "classify": choreo's class logits per kind of the frames
read unconditioned, with "cond_none", its conditioning row for no labels. Then the frames are walked again in onnxruntime with
no labels, each step's class logits are recomputed in numpy from the
graph's own weights (read with the onnx package): the state head
(h - ch) . cls.K.w + cls.K.b, plus, where the graph has a pose path (written
by choreo-train fit-heads), (v - cv) . wv + (v^2 - cv2) . wv2 + (m - cm) . wm
(all cls.K.*; a centre the graph lacks is 0) with v = bin / bins and
m the change magnitude (|offset| inside the radius, radius + 1 for an
escape, 0 for the first frame) over bins; and the mean over frames is
compared with choreo's.
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
report = {"onnxruntime": ort.__version__, "frames": len(frames), "max_abs_diff": worst}
ok = worst < 1e-4
if "classify" in dump:
    import onnx
    from onnx import numpy_helper
    w = {t.name: numpy_helper.to_array(t) for t in onnx.load(f"{model_dir}/{m['global_onnx']}").graph.initializer}
    kinds = [k for k, _ in c["classes"]]
    gc = Cache(c["global_layers"], c["global_heads"], c["max_frames"] + 1, c["d_global"] // c["global_heads"])
    # The unconditioned walk: choreo's conditioning row for no labels.
    cond = np.asarray(dump["cond_none"], np.float32)[None]
    gstep([0] * S, [NONE] * S, 1.0)
    sums = [np.zeros(len(v)) for _, v in c["classes"]]
    worst_step = 0.0
    for fi, frame in enumerate(frames):
        p1 = frames[fi - 1] if fi > 0 else None
        chg = [change(None if p1 is None else p1[s], frame[s]) for s in range(S)]
        f = gc.feeds()
        f.update({"val": np.asarray([frame], np.int64), "chg": np.asarray([chg], np.int64), "cond": cond,
                  "is_cond": np.asarray([[0.0]], np.float32), "pos": np.asarray([gc.len], np.int64)})
        out = g.run(None, f)
        gc.push(out, gnames)
        h = out[0].reshape(-1).astype(np.float64)
        v = np.asarray(frame, np.float64) / c["bins"]
        mag = np.asarray([abs(x - R) if x <= 2 * R else (R + 1 if x == ESC else 0) for x in chg], np.float64) / c["bins"]
        for ki, k in enumerate(kinds):
            z = lambda n: w.get(f"cls.{k}.{n}", 0.0)
            want = (h - z("ch")) @ w[f"cls.{k}.w"] + w[f"cls.{k}.b"]
            if f"cls.{k}.wv" in w:
                want = want + (v - z("cv")) @ w[f"cls.{k}.wv"] + (v * v - z("cv2")) @ w[f"cls.{k}.wv2"] \
                    + (mag - z("cm")) @ w[f"cls.{k}.wm"]
            got = out[gnames.index(f"cls_{k}")].reshape(-1)
            worst_step = max(worst_step, float(np.max(np.abs(got - want))))
            sums[ki] += got
    mean_diff = max(float(np.max(np.abs(s_ / len(frames) - np.asarray(dump["classify"][ki]))))
                    for ki, s_ in enumerate(sums))
    report.update({"class_step_vs_numpy": worst_step, "class_mean_vs_choreo": mean_diff,
                   "pose_path": any(f"cls.{k}.wv" in w for k in kinds)})
    ok = ok and worst_step < 1e-4 and mean_diff < 1e-4
print(json.dumps(report))
sys.exit(0 if ok else 1)
