#!/usr/bin/env bash
# choreo's HNSW and FAISS-HNSW side by side in one run, on the same
# synthetic vectors and queries, at the same M / efConstruction, each with
# efSearch set for recall@10 >= 0.99 against exact search:
#   cargo build --release && scripts/bench_index.sh [SIZES] [M] [EFC]
# BACKENDS=flat (or hnsw_rs, or both: the default) picks choreo's graphs;
# DTYPES=f32,f16 the flat graph's vector types (default f32); SERVER_BUILD=0
# skips the second, server-style build (ef calibrated on stored vectors).
# Needs numpy and faiss-cpu (pip install faiss-cpu). Prints a markdown
# table for bench/RESULTS.md.
set -euo pipefail
cd "$(dirname "$0")/.."
sizes=${1:-100000}
m=${2:-16}
efc=${3:-100}
bin=${CHOREO_BIN:-target/release/choreo}
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
server_build=(--server-build)
[ "${SERVER_BUILD:-1}" = 0 ] && server_build=()
"$bin" bench index --json "${server_build[@]}" --sizes "$sizes" --queries 200 --m "$m" --ef-construction "$efc" --dtype "${DTYPES:-f32}" \
  --backend "${BACKENDS:-hnsw_rs,flat}" --dump "$work" > "$work/choreo.json"
FAISS_M=$m FAISS_EFC=$efc python3 scripts/bench_faiss.py "$work" ${sizes//,/ } > "$work/faiss.json"
python3 - "$work/choreo.json" "$work/faiss.json" <<'PY'
import json, sys
rows = [r for f in sys.argv[1:] for r in json.load(open(f))["rows"]]
print("| n | index | dtype | efSearch (chosen by) | build s | p50 ms | p95 ms | QPS (1 thread) | recall@10 | RSS MB |")
print("|---|---|---|---|---|---|---|---|---|---|")
fmt = lambda v, p: "–" if v is None else f"{v:,.{p}f}"
for r in sorted(rows, key=lambda r: (r["n"], r["index"], r.get("dtype", ""))):
    ef = f'{r["ef_search"]} ({r["ef_chosen_by"]})' if "ef_search" in r else "–"
    name = r["index"] + (f' [{r["kernel"]}]' if "kernel" in r else "")
    print(f'| {r["n"]:,} | {name} | {r.get("dtype", "f32")} | {ef} | {fmt(r["build_s"], 1)} | {r["p50_ms"]:.3f} | {r["p95_ms"]:.3f} | '
          f'{r["qps"]:,.0f} | {r["recall_at_10"]:.4f} | {fmt(r["rss_mb"], 0)} |')
PY
