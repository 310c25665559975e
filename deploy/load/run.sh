#!/usr/bin/env bash
# Load runs against a release `choreo serve` on loopback (wrk from a second
# process): 60 s at 64 connections on /v1/query and on /v1/generate.
#   cargo build --release && deploy/load/run.sh [SECONDS] [CONNECTIONS]
# Needs wrk (Debian: apt-get install wrk) and python3. The store is all of
# $CHOREO_DATA (default ../shared/data), ingested at start-up into a
# temporary data directory. Prints each run's figures and the server's peak
# RSS (VmHWM).
set -euo pipefail
cd "$(dirname "$0")/../.."
secs=${1:-60}
conns=${2:-64}
data=${CHOREO_DATA:-$(cd .. && pwd)/shared/data}
bin=target/release/choreo
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
command -v wrk >/dev/null || { echo "wrk not found (apt-get install wrk)" >&2; exit 1; }
work=$(mktemp -d)
trap 'kill $pid 2>/dev/null; rm -rf "$work"' EXIT
"$bin" serve --data-dir "$work/data" --http-port 0 --grpc-port 0 \
  --ingest "$data" --workers "${CHOREO_WORKERS:-2}" --public-read 2> "$work/server.log" &
pid=$!
for _ in $(seq 600); do
  grep -q "REST on" "$work/server.log" && break
  kill -0 $pid 2>/dev/null || { cat "$work/server.log"; exit 1; }
  sleep 0.5
done
url=$(sed -n 's/.*REST on \(http:[^,]*\),.*/\1/p' "$work/server.log")
echo "server $url (pid $pid): $(grep ingested "$work/server.log")"
# Stored motions long enough for a 128-frame window, with their last start.
python3 - "$url" > "$work/ids.lua" <<'PY'
import json, sys, urllib.request
ms = json.load(urllib.request.urlopen(sys.argv[1] + "/v1/motions"))["motions"]
ok = [(m["id"], m["duration_s"] - 128 / 60 - 0.05) for m in ms if m["duration_s"] > 128 / 60 + 0.1]
print("return {" + ",".join("{%d,%.3f}" % m for m in ok) + "}")
PY
cp deploy/load/common.lua "$work/"
export LOAD_DIR="$work"
for endpoint in ${ENDPOINTS:-query generate}; do
  # Warm up (builds the HNSW index on the first query).
  curl -s -o /dev/null -X POST "$url/v1/query" -H 'content-type: application/json' \
    -d "{\"motion\":{\"id\":$(sed -n 's/return {{\([0-9]*\),.*/\1/p' "$work/ids.lua")}}" || true
  echo "== /v1/$endpoint: ${secs}s, $conns connections"
  wrk -t2 -c"$conns" -d"${secs}s" --timeout 30s -s "deploy/load/$endpoint.lua" "$url/v1/$endpoint"
done
echo "server peak RSS: $(grep VmHWM /proc/$pid/status)"
