"""Forward tokens/s of an exported choreo model in onnxruntime, on the window
`choreo bench model --dump W.json` wrote (same tokens, same positions).
Usage: python3 scripts/bench_onnxruntime.py MODEL_DIR W.json [REPEATS]"""
import json, sys, time
import numpy as np
import onnxruntime as ort

model_dir, window = sys.argv[1], sys.argv[2]
repeats = int(sys.argv[3]) if len(sys.argv) > 3 else 20
w = json.load(open(window))
so = ort.SessionOptions()
sess = ort.InferenceSession(f"{model_dir}/model.onnx", so, providers=["CPUExecutionProvider"])
t = len(w["tokens"])
feed = {"tokens": np.array([w["tokens"]], dtype=np.int64), "pos_a_ids": np.array([w["pos_a"]], dtype=np.int64)}
if "pos_b_ids" in w["inputs"]:
    feed["pos_b_ids"] = np.array([w["pos_b"]], dtype=np.int64)
bias = np.zeros((t, t), dtype=np.float32)
if w["objective"] == "causal":
    bias[np.triu_indices(t, 1)] = -1e9
feed["attn_bias"] = bias
for l in range(w["n_layers"]):
    for kv in "kv":
        feed[f"past_{kv}_{l}"] = np.zeros((1, w["n_heads"], 0, w["d_head"]), dtype=np.float32)
sess.run(None, feed)
t0 = time.perf_counter()
for _ in range(repeats):
    out = sess.run(None, feed)
per = (time.perf_counter() - t0) / repeats
print(json.dumps({"onnxruntime": ort.__version__, "window_tokens": t, "window_forward_ms": per * 1e3,
                  "forward_tokens_per_s": t / per, "logits_shape": list(out[0].shape)}))
