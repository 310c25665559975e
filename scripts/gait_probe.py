#!/usr/bin/env python3
"""How far a generated gait moves, against the real take it continues.

Against a running `choreo serve` (docs/RESULTS.md, "Session 36"):
  scripts/gait_probe.py PORT TOKEN TAKE.bvh [--content walk] [--sampling JSON]
      [--seeds 0 1 2] [--choreo target/release/choreo]
  scripts/gait_probe.py --real-only TAKE.bvh ...   (no server: the takes alone)

- real: the take's knee flexion (the hip-knee-ankle angle from
  `choreo positions`, resampled to 20 fps), its range within each second and
  its mean change a frame, the median change and the share of frames whose
  change passes 12 and 24 degrees (the bundled style and content
  `max_jump` caps, in 1-degree bins), and the change at the cut points below;
- continued: `POST /v1/generate` with the whole take as `seed_motion`, 200
  frames per seed; the generated knees' flexion (the norm of their
  axis-angle rotations), the same figures per second;
- one step: the take cut at 2 s, 2.25 s, ... (`choreo convert --fps 20
  --frames 0:T`), each cut continued 3 frames per seed; the knees' change
  between generated frames 1 -> 2 and 2 -> 3, beside the real take's change
  over the same frames.
"""
import argparse
import base64
import json
import os
import subprocess
import sys
import tempfile
import urllib.request

import numpy as np

FPS = 20
# Hip, knee, ankle names per side, as the corpora spell them.
LEGS = [("Left_Hip", "Left_Knee", "Left_Ankle"), ("Right_Hip", "Right_Knee", "Right_Ankle"),
        ("UpperLeg_L", "LowerLeg_L", "Foot_L"), ("UpperLeg_R", "LowerLeg_R", "Foot_R")]
KNEES = [3, 4]  # SMPL-13 order: pelvis, left hip, right hip, left knee, right knee, ...


def real_knees(choreo, take):
    out = subprocess.run([choreo, "positions", take], check=True, capture_output=True, text=True).stdout
    d = json.loads(out)
    names, p, fps = d["joints"], np.array(d["positions"]), d["fps"]
    t = np.arange(0, (len(p) - 1) / fps, 1 / FPS) * fps
    i0 = np.floor(t).astype(int)
    w = (t - i0)[:, None, None]
    p = p[i0] * (1 - w) + p[np.minimum(i0 + 1, len(p) - 1)] * w
    knees = []
    for hip, knee, ankle in LEGS:
        if all(n in names for n in (hip, knee, ankle)):
            h, k, a = (names.index(n) for n in (hip, knee, ankle))
            u, v = p[:, h] - p[:, k], p[:, a] - p[:, k]
            cos = (u * v).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
            knees.append(180 - np.degrees(np.arccos(np.clip(cos, -1, 1))))
    if len(knees) != 2:
        raise SystemExit(f"{take}: no left and right hip/knee/ankle among {names}")
    return np.stack(knees, 1)


def generate(port, token, take, content, sampling, seed, frames):
    body = {"labels": {"content": content}, "frames": frames, "sampling": {"seed": seed, **sampling},
            "seed_motion": {"file": {"name": os.path.basename(take),
                                     "content_base64": base64.b64encode(open(take, "rb").read()).decode()}}}
    req = urllib.request.Request(f"http://127.0.0.1:{port}/v1/generate", data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json", "Authorization": f"Bearer {token}"})
    rot = np.array(json.load(urllib.request.urlopen(req))["output"]["rotations"])
    return np.degrees(np.linalg.norm(rot[:, KNEES], axis=2))


def per_second(k):
    d = np.abs(np.diff(k, axis=0))
    spans = range(0, len(k) - FPS + 1, FPS)
    return ([float(np.ptp(k[i:i + FPS], axis=0).mean()) for i in spans],
            [float(d[i:i + FPS - 1].mean()) for i in spans])


def real_summary(choreo, take):
    real = real_knees(choreo, take)
    rng, chg = per_second(real)
    d = np.abs(np.diff(real, axis=0))
    print(f"real {os.path.basename(take)}: range", " ".join(f"{x:.0f}" for x in rng), "| change",
          " ".join(f"{x:.1f}" for x in chg), f"| median {np.median(d):.1f}, over 12: {100 * (d > 12).mean():.0f} %,"
          f" over 24: {100 * (d > 24).mean():.0f} %")
    return real


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--real-only", nargs="+", metavar="TAKE", help="only the real takes' knee figures")
    if "--real-only" in sys.argv:
        ap.add_argument("--choreo", default="target/release/choreo")
        a = ap.parse_args()
        for take in a.real_only:
            real_summary(a.choreo, take)
        return
    ap.add_argument("port")
    ap.add_argument("token")
    ap.add_argument("take")
    ap.add_argument("--content", default="walk")
    ap.add_argument("--sampling", default="{}", help="JSON merged into the request's sampling")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--choreo", default="target/release/choreo")
    a = ap.parse_args()
    sampling = json.loads(a.sampling)
    real = real_summary(a.choreo, a.take)
    for seed in a.seeds:
        rng, chg = per_second(generate(a.port, a.token, a.take, a.content, sampling, seed, 200))
        print(f"continued, seed {seed}: range", " ".join(f"{x:.0f}" for x in rng),
              "| change", " ".join(f"{x:.1f}" for x in chg))
    cuts = range(2 * FPS, len(real) - 2, FPS // 4)
    gen1, gen2, real1, real2 = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for t in cuts:
            cut = os.path.join(tmp, f"cut{t}.bvh")
            subprocess.run([a.choreo, "convert", a.take, cut, "--fps", str(FPS), "--frames", f"0:{t}"],
                           check=True, capture_output=True)
            real1.append(np.abs(real[t + 1] - real[t]))
            real2.append(np.abs(real[t + 2] - real[t + 1]))
            for seed in a.seeds:
                k = generate(a.port, a.token, cut, a.content, sampling, seed, 3)
                gen1.append(np.abs(k[1] - k[0]))
                gen2.append(np.abs(k[2] - k[1]))
    g1, g2, r1, r2 = (np.concatenate(x) for x in (gen1, gen2, real1, real2))
    print(f"one step ({len(cuts)} cuts x {len(a.seeds)} seeds): generated 1->2 mean {g1.mean():.1f} median "
          f"{np.median(g1):.1f} p90 {np.percentile(g1, 90):.1f}, 2->3 mean {g2.mean():.1f}; real 1->2 mean "
          f"{r1.mean():.1f} median {np.median(r1):.1f} p90 {np.percentile(r1, 90):.1f}, 2->3 mean {r2.mean():.1f}")


if __name__ == "__main__":
    main()
