#!/usr/bin/env python3
"""choreo's music features against librosa on the music in the data folder.

For every audio file under DATA/music, `choreo dev audio` writes its
30,720 Hz mono samples and features. librosa then computes, on those same
samples: 20 MFCC (n_fft 2048, hop 512), onset strength, onset peaks
(onset_detect), and the onset strength of the HPSS percussive part. Checks:

- every MFCC coefficient's time series and the onset curves correlate
  >= 0.99 with librosa's;
- >= 95 % of the peaks on either side have a partner within one frame;
- our resampler against librosa.load(sr=30720) (soxr): correlation >= 0.99.

It also times both (feature extraction speed, for bench/RESULTS.md).

usage: check_audio_librosa.py CHOREO_BIN DATA_DIR
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

try:
    import librosa
except ImportError:  # pragma: no cover
    if os.environ.get("CHOREO_REQUIRE_REFS") == "1":
        raise
    print("SKIP: librosa is not installed (pip install -r scripts/requirements.txt)")
    sys.exit(0)

SR, N_FFT, HOP = 30720, 2048, 512


def corr(a, b):
    n = min(len(a), len(b))
    a, b = np.asarray(a[:n], float), np.asarray(b[:n], float)
    if a.std() == 0 or b.std() == 0:
        return 1.0 if np.allclose(a, b) else 0.0
    return float(np.corrcoef(a, b)[0, 1])


def matched(xs, ys):
    if len(xs) == 0:
        return 1.0 if len(ys) == 0 else 0.0
    ys = np.asarray(ys)
    return float(np.mean([np.min(np.abs(ys - x)) <= 1 if len(ys) else False for x in xs]))


def main():
    binary, data = sys.argv[1], sys.argv[2]
    music = os.path.join(data, "music")
    files = sorted(
        os.path.join(music, f)
        for f in os.listdir(music)
        if f.lower().endswith((".ogg", ".wav", ".mp3"))
    )
    assert files, f"no audio in {music}"
    failures = []
    rows = []
    for f in files:
        with tempfile.TemporaryDirectory() as out:
            subprocess.run([binary, "dev", "audio", "--music", f, "--out", out], check=True, capture_output=True)
            y = np.load(os.path.join(out, "y.npy")).astype(np.float32)
            ours = json.load(open(os.path.join(out, "features.json")))
        t = time.time()
        mf = librosa.feature.mfcc(y=y, sr=SR, n_mfcc=20, n_fft=N_FFT, hop_length=HOP)
        on = librosa.onset.onset_strength(y=y, sr=SR, n_fft=N_FFT, hop_length=HOP)
        pk = librosa.onset.onset_detect(onset_envelope=on, sr=SR, hop_length=HOP)
        D = np.abs(librosa.stft(y, n_fft=N_FFT, hop_length=HOP))
        _, P = librosa.decompose.hpss(D, kernel_size=31)
        pdb = librosa.power_to_db(librosa.feature.melspectrogram(S=P**2, sr=SR, n_fft=N_FFT, hop_length=HOP))
        pon = librosa.onset.onset_strength(S=pdb, sr=SR, n_fft=N_FFT, hop_length=HOP)
        ppk = librosa.onset.onset_detect(onset_envelope=pon, sr=SR, hop_length=HOP)
        librosa_s = time.time() - t
        t = time.time()
        ref_y = librosa.load(f, sr=SR, mono=True)[0]
        load_s = time.time() - t
        ours_mfcc = np.asarray(ours["mfcc"]).T
        assert ours_mfcc.shape == mf.shape, (ours_mfcc.shape, mf.shape)
        c_mfcc = min(corr(ours_mfcc[k], mf[k]) for k in range(20))
        c_on = corr(ours["onset"], on)
        c_pon = corr(ours["percussive_onset"], pon)
        m1, m2 = matched(ours["peaks"], pk), matched(pk, ours["peaks"])
        p1, p2 = matched(ours["percussive_peaks"], ppk), matched(ppk, ours["percussive_peaks"])
        c_y = corr(y, ref_y)
        name = os.path.basename(f)
        rows.append((name, c_mfcc, c_on, c_pon, m1, m2, p1, p2, c_y, ours["analysis_seconds"], librosa_s, len(y) / SR))
        print(
            f"{name[:40]:40s} mfcc min r {c_mfcc:.5f}  onset r {c_on:.5f}  percussive onset r {c_pon:.5f}  "
            f"peaks matched {m1:.3f}/{m2:.3f} ({len(ours['peaks'])} vs {len(pk)})  "
            f"percussive peaks {p1:.3f}/{p2:.3f}  resampler r {c_y:.5f}  "
            f"time choreo {ours['analysis_seconds']:.2f} s (incl. resampling + HPSS) vs librosa {librosa_s:.2f} s (+ load/soxr {load_s:.2f} s) for {len(y) / SR:.1f} s"
        )
        for what, v, lim in [
            ("mfcc", c_mfcc, 0.99),
            ("onset", c_on, 0.99),
            ("percussive onset", c_pon, 0.99),
            ("peaks ours→librosa", m1, 0.95),
            ("peaks librosa→ours", m2, 0.95),
            ("resampler", c_y, 0.99),
        ]:
            if not v >= lim:
                failures.append(f"{name}: {what} {v:.5f} < {lim}")
    if failures:
        print("FAIL\n" + "\n".join(failures))
        sys.exit(1)
    print(f"OK: {len(rows)} files")


if __name__ == "__main__":
    main()
