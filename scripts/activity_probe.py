#!/usr/bin/env python3
"""How much generated clips move, second by second, against real takes.

Against a running `choreo serve` (docs/RESULTS.md, "Session 39"):
  scripts/activity_probe.py PORT TOKEN --kind style --values active,sad,...
      [--seeds 0 1] [--frames 200] [--sampling JSON]
  scripts/activity_probe.py --real GLOB [--every 4] [--choreo target/release/choreo]
      (no server: real takes, e.g. '../shared/data/bandai/dataset-*/*.bvh')

Activity is the joints' angular speed: the sum over joints and axis-angle
components of |change a frame|, times the frame rate (rad/s), on the
13-joint body at 20 fps (real takes go through `choreo convert --joints
smpl13 --fps 20`). Generated: `POST /v1/generate` with the labels only
(the API's defaults, so a labelled request starts from a style exemplar),
one clip per value and seed; printed per clip and second, then across
clips per second the mean and spread of log activity, and each second's
correlation with the first (does a clip keep its own level?). Real: each
take's mean log activity, and the mean and spread over takes.
"""
import argparse
import glob
import json
import os
import subprocess
import tempfile
import urllib.request

import numpy as np


def activity(rot, fps):
    """Per-frame angular speed (rad/s) of [frames, joints, 3] axis-angles."""
    return np.abs(np.diff(rot, axis=0)).sum(axis=(1, 2)) * fps


def generated(a):
    extra = json.loads(a.sampling) if a.sampling else {}
    rows = []
    for value in a.values.split(","):
        for seed in a.seeds:
            body = {"labels": {a.kind: value}, "frames": a.frames,
                    "sampling": {"seed": seed, **extra}}
            req = urllib.request.Request(
                f"http://127.0.0.1:{a.port}/v1/generate", data=json.dumps(body).encode(),
                headers={"Content-Type": "application/json",
                         "Authorization": f"Bearer {a.token}"})
            out = json.load(urllib.request.urlopen(req))["output"]
            fps = int(round(out.get("fps", 20)))
            act = activity(np.array(out["rotations"]), fps)
            per_s = np.array([act[i:i + fps].mean() for i in range(0, len(act) - fps + 1, fps)])
            rows.append(per_s)
            print(value, seed, " ".join(f"{x:.0f}" for x in per_s), flush=True)
    n = min(len(r) for r in rows)
    la = np.log(np.array([r[:n] for r in rows]))
    print("mean log activity by second ", " ".join(f"{x:.2f}" for x in la.mean(0)))
    print("spread (std) by second      ", " ".join(f"{x:.2f}" for x in la.std(0)))
    print("correlation with the first s", " ".join(
        f"{np.corrcoef(la[:, 0], la[:, k])[0, 1]:.2f}" for k in range(n)))


def real(a):
    files = sorted(glob.glob(a.real))[::a.every]
    if not files:
        raise SystemExit(f"--real: no file matches {a.real!r}")
    vals = []
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "take.npz")
        for f in files:
            subprocess.run([a.choreo, "convert", f, out, "--joints", "smpl13", "--fps", "20"],
                           check=True, capture_output=True)
            poses = np.load(out)["poses"]
            vals.append(activity(poses.reshape(len(poses), -1, 3), 20).mean())
    la = np.log(np.array(vals))
    print(f"{len(vals)} takes: mean log activity {la.mean():.2f}, spread {la.std():.2f}, "
          f"median {np.exp(np.median(la)):.0f} rad/s")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("port", nargs="?")
    p.add_argument("token", nargs="?")
    p.add_argument("--kind", default="style")
    p.add_argument("--values")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--sampling", help="JSON object merged into each request's sampling")
    p.add_argument("--real", help="glob of real takes (no server)")
    p.add_argument("--every", type=int, default=1, help="with --real: every k-th file")
    p.add_argument("--choreo", default="target/release/choreo")
    a = p.parse_args()
    if a.real:
        real(a)
    elif a.port and a.token and a.values:
        generated(a)
    else:
        p.error("PORT TOKEN --values V1,V2,... (or --real GLOB)")


if __name__ == "__main__":
    main()
