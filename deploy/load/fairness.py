#!/usr/bin/env python3
"""Does one client in a retry storm push the others out? A release `choreo
serve` on loopback holds the AIST++ samples; a "storm" token sends queries
from several threads with no pause and ignores 429, while two "polite"
tokens each send one query, honour Retry-After, and think 50 ms between
answers. The same run is made without a rate limit and with one; each
prints answers/s per client and the polite clients' latency.

Usage: deploy/load/fairness.py [--bin target/release/choreo] [--seconds 15]
         [--rate 20] [--storm-threads 4] [--endpoint query|generate]
"""
import argparse, hashlib, http.client, json, os, re, statistics, subprocess, sys, tempfile, threading, time

p = argparse.ArgumentParser()
p.add_argument("--bin", default="target/release/choreo")
p.add_argument("--data", default=os.environ.get("CHOREO_DATA", "../shared/data"))
p.add_argument("--seconds", type=float, default=15)
p.add_argument("--rate", type=float, default=20)
p.add_argument("--storm-threads", type=int, default=4)
p.add_argument("--endpoint", choices=["query", "generate"], default="query")
args = p.parse_args()

PATH, BODY = {
    "query": ("/v1/query", json.dumps({"motion": {"id": 1}, "start_s": 1.0, "k": 5, "embedding": "dct"})),
    # 2 s of generated dance: the heavy pool (--workers 2).
    "generate": ("/v1/generate", json.dumps({"labels": {"genre": "BR"}, "frames": 40, "sampling": {"seed": 1}})),
}[args.endpoint]


def sha(s):
    return "sha256:" + hashlib.sha256(s.encode()).hexdigest()


def run(rate):
    work = tempfile.mkdtemp()
    tokens = os.path.join(work, "tokens")
    with open(tokens, "w") as f:
        for name in ("storm", "polite1", "polite2"):
            f.write(f"{name} read {sha(name + '-secret')}\n")
    log = open(os.path.join(work, "server.log"), "w+")
    server = subprocess.Popen(
        [args.bin, "serve", "--data-dir", os.path.join(work, "data"), "--http-port", "0", "--grpc-port", "0",
         "--ingest", os.path.join(args.data, "aistpp"), "--tokens", tokens, "--workers", "2",
         "--rate-limit", str(rate), "--rate-burst", str(max(rate, 1))],
        stderr=log, stdout=subprocess.DEVNULL)
    try:
        port = None
        for _ in range(600):
            log.seek(0)
            m = re.search(r"REST on http://127\.0\.0\.1:(\d+)", log.read())
            if m:
                port = int(m.group(1))
                break
            if server.poll() is not None:
                sys.exit("server stopped:\n" + open(log.name).read())
            time.sleep(0.1)
        stats = {n: {"ok": 0, "limited": 0, "lat": []} for n in ("storm", "polite1", "polite2")}
        stop = time.time() + args.seconds

        def client(name, polite):
            c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            hdr = {"content-type": "application/json", "authorization": f"Bearer {name}-secret"}
            s = stats[name]
            while time.time() < stop:
                t0 = time.time()
                try:
                    c.request("POST", PATH, BODY, hdr)
                    r = c.getresponse()
                    r.read()
                except Exception:
                    c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
                    continue
                if r.status == 200:
                    s["ok"] += 1
                    s["lat"].append(time.time() - t0)
                    if polite:
                        time.sleep(0.05)
                elif r.status == 429:
                    s["limited"] += 1
                    if polite:
                        time.sleep(float(r.getheader("retry-after", "1")))
                else:
                    s.setdefault("other", 0)
                    s["other"] = s.get("other", 0) + 1

        threads = [threading.Thread(target=client, args=("storm", False)) for _ in range(args.storm_threads)]
        threads += [threading.Thread(target=client, args=(n, True)) for n in ("polite1", "polite2")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        out = {}
        for n, s in stats.items():
            lat = sorted(s["lat"])
            out[n] = {
                "answers_per_s": round(s["ok"] / args.seconds, 1),
                "limited_per_s": round(s["limited"] / args.seconds, 1),
                "p50_ms": round(1000 * statistics.median(lat), 1) if lat else None,
                "p99_ms": round(1000 * lat[int(0.99 * (len(lat) - 1))], 1) if lat else None,
            }
        return out
    finally:
        server.terminate()
        server.wait()


for rate in (0, args.rate):
    r = run(rate)
    total = sum(v["answers_per_s"] for v in r.values())
    polite = r["polite1"]["answers_per_s"] + r["polite2"]["answers_per_s"]
    print(json.dumps({"endpoint": args.endpoint, "rate_limit": rate or "off", "clients": r,
                      "polite_share_of_answers": round(polite / total, 3) if total else None}))
