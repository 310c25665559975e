#!/usr/bin/env python3
"""FAISS-HNSW (faiss-cpu) on the same vectors as `choreo bench index --dump DIR`:
build time, single-query latency p50/p95, QPS (1 thread), recall@10 against
choreo's exact top-10. Same parameters as choreo: M=24, efConstruction=200,
efSearch=128, cosine (inner product on L2-normalised vectors).

Usage: bench_faiss.py DIR N [N ...]
FAISS_M and FAISS_EFC override M and efConstruction (the 1M run used 16 / 100,
as choreo's 1M run did).
"""
import json, os, sys, time
import numpy as np
import faiss

d = sys.argv[1]
q = np.load(f"{d}/queries.npy").astype(np.float32)
faiss.normalize_L2(q)
for n in map(int, sys.argv[2:]):
    x = np.load(f"{d}/base_{n}.npy").astype(np.float32)
    gt = np.load(f"{d}/gt_{n}.npy").astype(np.int64)
    faiss.normalize_L2(x)
    faiss.omp_set_num_threads(2)
    m, efc = int(os.environ.get("FAISS_M", 24)), int(os.environ.get("FAISS_EFC", 200))
    ix = faiss.IndexHNSWFlat(x.shape[1], m, faiss.METRIC_INNER_PRODUCT)
    ix.hnsw.efConstruction = efc
    t = time.perf_counter()
    ix.add(x)
    build = time.perf_counter() - t
    ix.hnsw.efSearch = 128
    faiss.omp_set_num_threads(1)
    flat = faiss.IndexFlatIP(x.shape[1])
    flat.add(x)
    res = {}
    for name, index in [("faiss_flat", flat), ("faiss_hnsw", ix)]:
        lat, rec = [], 0.0
        for i in range(len(q)):
            t = time.perf_counter()
            _, I = index.search(q[i:i + 1], 10)
            lat.append((time.perf_counter() - t) * 1e3)
            rec += len(set(I[0]) & set(gt[i])) / 10
        lat = np.sort(lat)
        res[name] = {"p50_ms": float(np.percentile(lat, 50)), "p95_ms": float(np.percentile(lat, 95)),
                     "qps_1thread": float(1e3 * len(lat) / lat.sum()), "recall_at_10": rec / len(q)}
    res["faiss_hnsw"].update({"build_s": build, "m": m, "ef_construction": efc})
    print(json.dumps({"n": n, "dim": x.shape[1], "queries": len(q), **res}))
