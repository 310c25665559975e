#!/usr/bin/env python3
"""Do writes stall reads? A release `choreo serve` on loopback holds the real
archive ($CHOREO_DATA, default ../shared/data) less some held-out Bandai
takes. Three phases, each with query clients (by stored id, random start)
and a /healthz poller:

  idle       queries only;
  ingest     the held-out takes uploaded one by one (POST /v1/motions);
  saturated  generate clients keep every heavy permit busy, and more query
             clients than cores keep the light pool full.

Prints a markdown table of query and /healthz latency per phase.

  cargo build --release && python3 deploy/load/writes.py [--takes 50]
"""
import argparse
import base64
import json
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request

TOKEN = "bench-writes"


def call(url, body=None, token=False, timeout=120):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method="POST" if body is not None else "GET")
    req.add_header("content-type", "application/json")
    if token:
        req.add_header("authorization", f"Bearer {TOKEN}")
    t = time.perf_counter()
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            r.read()
            status = r.status
    except urllib.error.HTTPError as e:
        e.read()
        status = e.code
    return status, time.perf_counter() - t


def pct(xs, p):
    if not xs:
        return float("nan")
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(p / 100 * (len(xs) - 1))))]


class Phase:
    def __init__(self, name):
        self.name = name
        self.query, self.health, self.statuses = [], [], {}
        self.stop = threading.Event()
        self.slow = []
        self.t0 = time.perf_counter()
        self.lock = threading.Lock()

    def note(self, kind, status, dt):
        with self.lock:
            key = f"{kind} {status}"
            self.statuses[key] = self.statuses.get(key, 0) + 1
            if status == 200 and kind in ("query", "health"):
                (self.query if kind == "query" else self.health).append(dt)


def querier(base, motions, phase, seed):
    rng = random.Random(seed)
    while not phase.stop.is_set():
        mid, longest = rng.choice(motions)
        body = {"motion": {"id": mid}, "start_s": round(rng.uniform(0, longest), 2), "k": 10}
        phase.note("query", *call(base + "/v1/query", body))


def poller(base, phase):
    while not phase.stop.is_set():
        status, dt = call(base + "/healthz")
        phase.note("health", status, dt)
        if dt > 0.1:
            phase.slow.append((round(time.perf_counter() - phase.t0, 2), round(dt * 1e3)))
        time.sleep(0.05)


def generator(base, phase, seed):
    rng = random.Random(seed)
    while not phase.stop.is_set():
        body = {"frames": 40, "sampling": {"temperature": 0.95, "top_p": 0.95, "seed": rng.randint(1, 10**6)}}
        status, dt = call(base + "/v1/generate", body)
        phase.note("generate", status, dt)
        if status == 429:
            time.sleep(0.02)


def run_phase(name, base, motions, seconds=None, queriers=2, generators=0, writer=None):
    phase = Phase(name)
    threads = [threading.Thread(target=querier, args=(base, motions, phase, i)) for i in range(queriers)]
    threads.append(threading.Thread(target=poller, args=(base, phase)))
    threads += [threading.Thread(target=generator, args=(base, phase, 100 + i)) for i in range(generators)]
    for t in threads:
        t.start()
    t0 = time.perf_counter()
    if writer:
        writer()
    else:
        time.sleep(seconds)
    phase.seconds = time.perf_counter() - t0
    if phase.slow:
        print(f"{name}: /healthz over 100 ms at (s, ms): {phase.slow}", file=sys.stderr)
    phase.stop.set()
    for t in threads:
        t.join()
    return phase


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release/choreo")
    ap.add_argument("--data", default=os.environ.get("CHOREO_DATA", "../shared/data"))
    ap.add_argument("--takes", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=20)
    ap.add_argument("--cores", type=int, default=os.cpu_count())
    ap.add_argument("--saturated-runs", type=int, default=1)
    args = ap.parse_args()
    data = os.path.abspath(args.data)
    work = tempfile.mkdtemp(prefix="choreo-writes-")
    bandai = sorted(
        os.path.join(r, f)
        for d in ("dataset-1", "dataset-2")
        for r, _, fs in os.walk(os.path.join(data, "bandai", d))
        for f in fs
        if f.endswith(".bvh")
    )
    held = bandai[:: max(1, len(bandai) // max(1, args.takes))][: args.takes]
    corpus = os.path.join(work, "corpus")
    os.makedirs(corpus)
    for sub in ("aistpp", "aistpp-vrm", "cmu"):
        if os.path.exists(os.path.join(data, sub)):
            os.symlink(os.path.join(data, sub), os.path.join(corpus, sub))
    os.makedirs(os.path.join(corpus, "bandai"))
    for f in bandai:
        if f not in held:
            os.symlink(f, os.path.join(corpus, "bandai", os.path.relpath(f, data).replace("/", "__")))
    log = open(os.path.join(work, "server.log"), "w+")
    server = subprocess.Popen(
        [args.bin, "serve", "--data-dir", os.path.join(work, "data"), "--http-port", "0",
         "--grpc-port", "0", "--ingest", corpus, "--token", TOKEN, "--public-read", "--workers", "2"],
        stderr=log, stdout=log)
    try:
        base = None
        for _ in range(3600):
            log.seek(0)
            m = re.search(r"REST on (http://[^,\s]+)", log.read())
            if m:
                base = m.group(1)
                break
            if server.poll() is not None:
                log.seek(0)
                sys.exit("server stopped:\n" + log.read())
            time.sleep(0.5)
        ms = json.load(urllib.request.urlopen(base + "/v1/motions"))["motions"]
        motions = [(m["id"], m["duration_s"] - 128 / 60 - 0.05) for m in ms if m["duration_s"] > 128 / 60 + 0.1]
        print(f"server {base}: {len(ms)} motions stored, {len(held)} takes held out", file=sys.stderr)
        call(base + "/v1/query", {"motion": {"id": motions[0][0]}})  # builds the index
        phases = [run_phase("idle", base, motions, args.seconds)]

        def write_all():
            for f in held:
                body = {"motion": {"file": {"name": os.path.basename(f),
                                            "content_base64": base64.b64encode(open(f, "rb").read()).decode()}},
                        "labels": {"bench": "writes"}}
                status, dt = call(base + "/v1/motions", body, token=True)
                if status not in (200, 201):
                    sys.exit(f"ingest {f}: HTTP {status}")
                writes.append(dt)

        writes = []
        phases.append(run_phase(f"ingest {len(held)} takes", base, motions, writer=write_all))
        time.sleep(2)
        for _ in range(args.saturated_runs):
            phases.append(run_phase("saturated", base, motions, args.seconds,
                                    queriers=2 * args.cores, generators=4))
        idle_p99 = pct(phases[0].query, 99)
        print(f"\n{len(ms)} stored motions; ingest of {len(held)} takes: "
              f"p50 {pct(writes, 50) * 1e3:.0f} ms, max {max(writes, default=0) * 1e3:.0f} ms per take\n")
        print("| phase | s | queries | query p50 ms | query p99 ms | p99 / idle p99 | /healthz p50 ms | /healthz p99 ms | /healthz max ms | answers (kind status: count) |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for p in phases:
            print(f"| {p.name} | {p.seconds:.1f} | {len(p.query)} | {pct(p.query, 50) * 1e3:.1f} | "
                  f"{pct(p.query, 99) * 1e3:.1f} | {pct(p.query, 99) / idle_p99:.2f} | "
                  f"{pct(p.health, 50) * 1e3:.1f} | {pct(p.health, 99) * 1e3:.1f} | "
                  f"{max(p.health) * 1e3:.1f} | {json.dumps(p.statuses, sort_keys=True)} |")
    finally:
        server.terminate()
        server.wait()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
