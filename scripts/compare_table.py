#!/usr/bin/env python3
"""The flat GPT against the frame model: the table of #16's comparison.

Reads the `choreo eval generate --json` files that scripts/compare_models.sh
writes (RUN/{flat,frame}.gen.{bandai,vrm}.s{SEED}.json) and prints, per
corpus, each side's best row per seed and column, the per-seed values, their
means and how many seeds each side wins; then every row's means over the
seeds (every column from that one row).

Columns are read as SPEC §5 defines them: FID_k and FID_g lower; the
acceleration, jerk and foot-skating ratios to real by their distance from 1;
diversity and the frozen share by their distance from the real held-out
clips' own (the yardstick the eval prints beside them); conditioning higher.
Skating and the frozen share are also printed read as "lower", the reading
sessions 49-52 counted, where a side that holds still wins.

    scripts/compare_table.py RUN [SEEDS]     (SEEDS default "0 100 200 300")
"""
import json
import os
import statistics as st
import sys

COLUMNS = [  # name, value of a row, which way is better
    ("FID_k", lambda r: r["fid_k"], "low"),
    ("FID_g", lambda r: r["fid_g"], "low"),
    ("accel, distance from 1", lambda r: abs(r["accel_ratio"] - 1), "low"),
    ("jerk, distance from 1", lambda r: abs(r["jerk_ratio"] - 1), "low"),
    ("skating, distance from 1", lambda r: abs(r["skate_ratio"] - 1), "low"),
    ("diversity, distance from real", lambda r: abs(r["diversity"] - r["diversity_real"]), "low"),
    ("conditioning", lambda r: r["cond_acc"], "high"),
    ("frozen, distance from real", lambda r: abs(r["frozen"] - r["frozen_real"]), "low"),
    ("(skating, lower)", lambda r: r["skate_ratio"], "low"),
    ("(frozen, lower)", lambda r: r["frozen"], "low"),
]
CORPORA = [("bandai", "Bandai"), ("vrm", "AIST++-VRM")]


def rows(run, side, corpus, seed):
    path = f"{run}/{side}.gen.{corpus}.s{seed}.json"
    if not os.path.exists(path) or os.path.getsize(path) == 0:
        return None
    return json.load(open(path))["rows"]


def best(rs, value, how):
    vals = [value(r) for r in rs if value(r) is not None]
    if not vals:
        return None
    return min(vals) if how == "low" else max(vals)


def fmt(x):
    return "-" if x is None else f"{x:.3g}"


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    run = sys.argv[1]
    seeds = (sys.argv[2] if len(sys.argv) > 2 else "0 100 200 300").split()
    for corpus, title in CORPORA:
        pairs = [(s, rows(run, "frame", corpus, s), rows(run, "flat", corpus, s)) for s in seeds]
        pairs = [(s, a, b) for s, a, b in pairs if a and b]
        if not pairs:
            continue
        print(f"\n## {title}: best row per seed and column (seeds {' '.join(s for s, _, _ in pairs)})\n")
        print("| column | frame model | flat GPT | frame mean | flat mean | frame ahead |")
        print("|---|---|---|---|---|---|")
        for name, value, how in COLUMNS:
            fr = [best(a, value, how) for _, a, _ in pairs]
            fl = [best(b, value, how) for _, _, b in pairs]
            ok = [(x, y) for x, y in zip(fr, fl) if x is not None and y is not None]
            if not ok:
                continue
            ahead = sum((x < y) if how == "low" else (x > y) for x, y in ok)
            fx, fy = [x for x, _ in ok], [y for _, y in ok]
            print(
                f"| {name} | {' / '.join(map(fmt, fx))} | {' / '.join(map(fmt, fy))} "
                f"| {fmt(st.mean(fx))} | {fmt(st.mean(fy))} | {ahead} of {len(ok)} |"
            )
        r = pairs[0][1][0]
        print(
            f"\nreal held-out clips: FID_k {fmt(r.get('fid_k_real_same_n'))}, "
            f"FID_g {fmt(r.get('fid_g_real_same_n'))} (real against real at the same count), "
            f"diversity {fmt(r['diversity_real'])}, frozen {fmt(r['frozen_real'])}, "
            f"conditioning {fmt(r['cond_acc_real'])}"
        )
        for side in ["frame", "flat"]:
            per = {}
            for s, a, b in pairs:
                for row in a if side == "frame" else b:
                    per.setdefault(row["sampling"], []).append(row)
            print(f"\n### {title}, {side}: each row's means over the seeds\n")
            print("| row | " + " | ".join(n for n, _, _ in COLUMNS) + " |")
            print("|---" * (len(COLUMNS) + 1) + "|")
            for name, rs in per.items():
                vals = []
                for _, value, _ in COLUMNS:
                    v = [value(x) for x in rs if value(x) is not None]
                    vals.append(fmt(st.mean(v)) if v else "-")
                print(f"| {name} | " + " | ".join(vals) + " |")


if __name__ == "__main__":
    main()
