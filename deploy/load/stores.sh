#!/usr/bin/env bash
# SQLite against PostgreSQL on the same corpus, one run, one machine:
# ingest throughput (TAKES AIST++-VRM dances uploaded one by one over REST),
# then query load (wrk, SECONDS at CONNS connections, random stored motion
# and start, k = 10) through one server; for PostgreSQL also through three
# replicas on the same database, the connections split over them.
#   cargo build --release && deploy/load/stores.sh [TAKES] [SECONDS] [CONNS]
# Needs wrk, python3 and PostgreSQL's server binaries (a throwaway server
# is started by scripts/pg_throwaway.sh and stopped at the end).
set -euo pipefail
cd "$(dirname "$0")/../.."
takes=${1:-60}
secs=${2:-20}
conns=${3:-32}
data=${CHOREO_DATA:-$(cd .. && pwd)/shared/data}
bin=target/release/choreo
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
command -v wrk >/dev/null || { echo "wrk not found (apt-get install wrk)" >&2; exit 1; }
work=$(mktemp -d)
chmod 755 "$work"  # the postgres user reaches its data folder inside
cleanup() {
  for f in "$work"/*.pid; do [ -f "$f" ] && kill "$(cat "$f")" 2>/dev/null || true; done
  scripts/pg_throwaway.sh stop "$work/pg" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
pgurl=$(scripts/pg_throwaway.sh start "$work/pg" "${PGPORT:-55441}")
admin=${pgurl%/*}/postgres
cp deploy/load/common.lua "$work/"
export LOAD_DIR="$work"

# start NAME ARGS...: a release server (pid in NAME.pid); prints its REST URL.
start() {
  local name=$1; shift
  "$bin" serve --http-port 0 --grpc-port 0 --model /nonexistent --token bench \
    --public-read --data-dir "$work/$name" "$@" > /dev/null 2> "$work/$name.log" &
  echo $! > "$work/$name.pid"
  for _ in $(seq 600); do
    grep -q "REST on" "$work/$name.log" && break
    sleep 0.2
  done
  sed -n 's/.*REST on \(http:[^,]*\),.*/\1/p' "$work/$name.log"
}

# ingest URL: upload the takes one by one, print the figures.
ingest() {
  python3 - "$1" "$data/aistpp-vrm/motions" "$takes" <<'PY'
import base64, json, os, sys, time, urllib.request
url, folder, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
files = sorted(f for f in os.listdir(folder) if f.endswith(".pkl"))[:n]
windows, t0 = 0, time.perf_counter()
for f in files:
    body = json.dumps({"motion": {"file": {"name": f, "content_base64":
        base64.b64encode(open(os.path.join(folder, f), "rb").read()).decode()}}}).encode()
    req = urllib.request.Request(url + "/v1/motions", body, {"Content-Type": "application/json",
        "Authorization": "Bearer bench"})
    windows += json.load(urllib.request.urlopen(req))["windows"]
dt = time.perf_counter() - t0
print(f"ingest: {len(files)} takes, {windows} windows in {dt:.2f} s: {len(files)/dt:.1f} takes/s, {windows/dt:.0f} windows/s")
PY
}

# ids URL: the stored motions a query may start in (for query.lua).
ids() {
  python3 - "$1" > "$work/ids.lua" <<'PY'
import json, sys, urllib.request
ms = json.load(urllib.request.urlopen(sys.argv[1] + "/v1/motions"))["motions"]
ok = [(m["id"], m["duration_s"] - 128 / 60 - 0.05) for m in ms if m["duration_s"] > 128 / 60 + 0.1]
print("return {" + ",".join("{%d,%.3f}" % m for m in ok) + "}")
PY
  # Warm up: build the index.
  curl -s -o /dev/null -X POST "$1/v1/query" -H 'content-type: application/json' \
    -d "{\"motion\":{\"id\":$(sed -n 's/return {{\([0-9]*\),.*/\1/p' "$work/ids.lua")}}"
}

echo "== SQLite (embedded)"
u=$(start sqlite)
ingest "$u"
ids "$u"
wrk -t2 -c"$conns" -d"${secs}s" --timeout 30s -s deploy/load/query.lua "$u/v1/query"
kill "$(cat "$work/sqlite.pid")"; rm "$work/sqlite.pid"

echo "== PostgreSQL, one server"
psql -q "$admin" -c "CREATE DATABASE bench" >/dev/null
store=${pgurl%/*}/bench
u1=$(start pg1 --store "$store")
ingest "$u1"
ids "$u1"
wrk -t2 -c"$conns" -d"${secs}s" --timeout 30s -s deploy/load/query.lua "$u1/v1/query"

echo "== PostgreSQL, three replicas ($conns connections split over them)"
u2=$(start pg2 --store "$store")
u3=$(start pg3 --store "$store")
ids "$u2" && ids "$u3"
per=$(( conns / 3 ))
w=()
for u in "$u1" "$u2" "$u3"; do
  wrk -t1 -c"$per" -d"${secs}s" --timeout 30s -s deploy/load/query.lua "$u/v1/query" > "$work/wrk-${u##*:}.txt" &
  w+=($!)
done
wait "${w[@]}"
for u in "$u1" "$u2" "$u3"; do echo "-- $u"; cat "$work/wrk-${u##*:}.txt" | grep -E "req/s|5xx|latency"; done
python3 - "$work" <<'PY'
import glob, re, sys
total = sum(float(re.search(r"([0-9.]+) req/s", open(f).read()).group(1)) for f in glob.glob(sys.argv[1] + "/wrk-*.txt"))
print(f"three replicas together: {total:.1f} req/s")
PY
