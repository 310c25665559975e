#!/usr/bin/env bash
# Trains the frame-level model on every corpus, exports it, and prints its
# held-out tables beside the baselines and the flat model (README,
# "The frame model"). About 90 minutes on a 2-core VM.
#   scripts/frame_model.sh RUN_DIR [STEPS]
set -euo pipefail
run=${1:?run folder}
steps=${2:-550}
T=target/release/choreo-train
C=target/release/choreo
cargo build --release --all-features --bins
classes="--classify genre --classify dancer --classify situation --classify content --classify style"
# Resumable: rerun with --resume (and --steps to reshape the schedule).
$T frame --out "$run" --frames 200 --batch 6 --steps "$steps" --eval-every 100 $classes > "$run.table.json"
$T eval-frame --checkpoint "$run" --export "$run/export" > "$run.table.json"
$C bench model --model "$run/export" --frames 600
$C eval generate --model "$run/export" --data "${CHOREO_DATA:-../shared/data}/bandai" --labels style --per-label 1 --json
$C eval generate --model "$run/export" --data "${CHOREO_DATA:-../shared/data}/aistpp-vrm/motions" --labels genre --per-label 2 --json
