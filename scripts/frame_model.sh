#!/usr/bin/env bash
# Trains the frame-level model on every corpus, exports it, and prints its
# held-out tables beside the baselines and the flat model (README,
# "The frame model"). Three stages, as the bundled model was made: from
# scratch (about 70 minutes on a 2-core VM), a warm start that adds the
# conditioning at every frame (--cond-every; about 65 minutes), and a
# continuation at lr 1e-4 with Bandai drawn twice as often (600 steps, then
# stretched to 850; about 75 minutes), whose class heads are then fitted in
# closed form (fit-heads) and whose style exemplars are written.
#   scripts/frame_model.sh RUN_DIR [STEPS] [COND_STEPS] [MORE_STEPS]
# ROOT_VELOCITY=heading trains the whole lineage with the root velocity in
# the body's heading frame (docs/RESULTS.md, "Session 34"); default world.
set -euo pipefail
run=${1:?run folder}
steps=${2:-550}
cond_steps=${3:-500}
more_steps=${4:-850}
T=target/release/choreo-train
C=target/release/choreo
cargo build --release --all-features --bins
classes="--classify genre --classify dancer --classify situation --classify content --classify style"
# Resumable: rerun with --resume (and --steps to reshape the schedule).
$T frame --out "$run" --frames 200 --batch 6 --steps "$steps" --eval-every 100 $classes \
    --root-velocity "${ROOT_VELOCITY:-world}" > "$run.table.json"
$T frame --out "$run-cond" --init-from "$run" --cond-every --frames 200 --batch 6 --steps "$cond_steps" --lr 5e-4 --eval-every 100 $classes > /dev/null
$T frame --out "$run-more" --init-from "$run-cond/export" --cond-every --frames 200 --batch 6 --steps 600 --lr 1e-4 --eval-every 100 --corpus-weight bandai=2 > /dev/null
$T frame --out "$run-more" --resume --steps "$more_steps" > /dev/null
$T eval-frame --checkpoint "$run-more" --export "$run-more/export" > "$run-more.table.json"
$T fit-heads --model "$run-more/export" --out "$run-more/model" $classes > "$run-more.heads.json"
D=${CHOREO_DATA:-../shared/data}
$C exemplars --model "$run-more/model" --data "$D/bandai" --data "$D/aistpp-vrm" --data "$D/aistpp" --data "$D/cmu"
$C bench model --model "$run-more/model" --frames 600
# The default sampling (t 1, top-p 0.95, keep_near 2, max_jump 48; README,
# "Exemplars the heads choose"), on two sets of clips.
for seed in 0 100; do
  for n in 1 4; do
    $C eval generate --model "$run-more/model" --data "$D/bandai" --labels style --per-label 6 --seed $seed \
        --sampling 1:0:0.95:1:2:48 --exemplar auto --candidates $n --json
    $C eval generate --model "$run-more/model" --data "$D/aistpp-vrm/motions" --labels genre --per-label 12 --seed $seed \
        --sampling 1:0:0.95:1:2:48 --exemplar auto --candidates $n --json
  done
  # Steering by the class heads (docs/RESULTS.md, "Steering"): 4 continuations of
  # 20 frames ranked per round.
  $C eval generate --model "$run-more/model" --data "$D/bandai" --labels style --per-label 6 --seed $seed \
      --sampling 1:0:0.95:1:2:48 --exemplar auto --candidates 4 --rank-every 20 --json
  $C eval generate --model "$run-more/model" --data "$D/aistpp-vrm/motions" --labels genre --per-label 12 --seed $seed \
      --sampling 1:0:0.95:1:2:48 --exemplar auto --candidates 4 --rank-every 20 --json
done
