#!/usr/bin/env bash
# Trains the frame-level model on every corpus, exports it, and prints its
# held-out tables beside the baselines and the flat model (README,
# "The frame model"). Two stages, as the bundled model was made: from
# scratch (about 70 minutes on a 2-core VM), then a warm start that adds the
# conditioning at every frame (--cond-every; about 65 minutes).
#   scripts/frame_model.sh RUN_DIR [STEPS] [COND_STEPS]
set -euo pipefail
run=${1:?run folder}
steps=${2:-550}
cond_steps=${3:-500}
T=target/release/choreo-train
C=target/release/choreo
cargo build --release --all-features --bins
classes="--classify genre --classify dancer --classify situation --classify content --classify style"
# Resumable: rerun with --resume (and --steps to reshape the schedule).
$T frame --out "$run" --frames 200 --batch 6 --steps "$steps" --eval-every 100 $classes > "$run.table.json"
$T frame --out "$run-cond" --init-from "$run" --cond-every --frames 200 --batch 6 --steps "$cond_steps" --lr 5e-4 --eval-every 100 $classes > /dev/null
$T eval-frame --checkpoint "$run-cond" --export "$run-cond/export" > "$run-cond.table.json"
$C bench model --model "$run-cond/export" --frames 600
$C eval generate --model "$run-cond/export" --data "${CHOREO_DATA:-../shared/data}/bandai" --labels style --per-label 1 --json
$C eval generate --model "$run-cond/export" --data "${CHOREO_DATA:-../shared/data}/aistpp-vrm/motions" --labels genre --per-label 2 --json
