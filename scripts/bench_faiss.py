#!/usr/bin/env python3
"""FAISS-HNSW (faiss-cpu) on the same vectors as `choreo bench index --dump DIR`.

Prints {"rows": [...]} in choreo's row shape (n, index, dtype, build_s,
p50_ms, p95_ms, qps, recall_at_10, rss_mb): exact (IndexFlatIP) and
"faiss-hnsw" at efSearch 128 and at the smallest efSearch on choreo's ladder
whose recall@10 against choreo's exact top-10 reaches FAISS_TARGET (0.99).
Cosine: inner product on L2-normalised vectors. The build uses every core
(FAISS_THREADS, default all); queries run one at a time on one thread.

Usage: bench_faiss.py DIR N [N ...]
FAISS_M and FAISS_EFC set M and efConstruction (default 16 and 100).
"""
import json, os, resource, sys, time
import numpy as np
import faiss


def rss_mb():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def measure(index, q, gt):
    lat, rec = [], 0.0
    for i in range(len(q)):
        t = time.perf_counter()
        _, I = index.search(q[i:i + 1], 10)
        lat.append((time.perf_counter() - t) * 1e3)
        rec += len(set(I[0]) & set(gt[i])) / 10
    lat = np.sort(lat)
    return {"p50_ms": float(np.percentile(lat, 50)), "p95_ms": float(np.percentile(lat, 95)),
            "qps": float(1e3 * len(lat) / lat.sum()), "recall_at_10": rec / len(q)}


d = sys.argv[1]
target = float(os.environ.get("FAISS_TARGET", 0.99))
q = np.load(f"{d}/queries.npy").astype(np.float32)
faiss.normalize_L2(q)
rows = []
for n in map(int, sys.argv[2:]):
    x = np.load(f"{d}/base_{n}.npy").astype(np.float32)
    gt = np.load(f"{d}/gt_{n}.npy").astype(np.int64)
    faiss.normalize_L2(x)
    m, efc = int(os.environ.get("FAISS_M", 16)), int(os.environ.get("FAISS_EFC", 100))
    faiss.omp_set_num_threads(int(os.environ.get("FAISS_THREADS", os.cpu_count())))
    ix = faiss.IndexHNSWFlat(x.shape[1], m, faiss.METRIC_INNER_PRODUCT)
    ix.hnsw.efConstruction = efc
    t = time.perf_counter()
    ix.add(x)
    build = time.perf_counter() - t
    faiss.omp_set_num_threads(1)
    flat = faiss.IndexFlatIP(x.shape[1])
    flat.add(x)
    base = {"n": n, "dtype": "f32", "rss_mb": rss_mb()}
    rows.append({**base, "index": "faiss-flat", "build_s": None, **measure(flat, q, gt)})
    del flat
    common = {**base, "index": "faiss-hnsw", "build_s": build, "m": m, "ef_construction": efc}
    ix.hnsw.efSearch = 128
    rows.append({**common, "ef_search": 128, "ef_chosen_by": "fixed", **measure(ix, q, gt)})
    for ef in [10, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512]:
        ix.hnsw.efSearch = ef
        r = measure(ix, q, gt)
        if r["recall_at_10"] >= target or ef == 512:
            rows.append({**common, "ef_search": ef, "ef_chosen_by": f"recall>={target}", **r})
            break
print(json.dumps({"rows": rows, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
