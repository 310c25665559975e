#!/usr/bin/env bash
# The small-scale runs behind README's Tables 4.4, 4.5 and 4.6 (thesis 000
# §4.5): every run is the same small model (d_model 64, 2 layers, 2 heads,
# 8-frame window, batch 8) for the same number of steps, on this machine.
# Usage: scripts/lm_tables.sh OUT_DIR [STEPS]   (CHOREO_DATA = data root)
set -euo pipefail
out=${1:?out dir}; steps=${2:-300}
bin=${CHOREO_TRAIN:-target/release/choreo-train}
small="--d-model 64 --layers 2 --heads 2 --frames 8 --batch 8 --eval-every $steps --lr 2e-3"
mkdir -p "$out"
run() { local name=$1; shift; echo "== $name"; "$bin" train --out "$out/$name" $small "$@" > "$out/$name.json" 2> "$out/$name.log"; }
# Table 4.4: positional embedding × objective (all corpora).
for p in absolute frame-slot; do for o in causal masked; do
  run "t44-$p-$o" --steps "$steps" --positions "$p" --objective "$o"
done; done
# Table 4.5: joints × frame rate (AIST++ only, as in the thesis).
for j in 13 24; do for f in 20 60; do
  run "t45-j$j-f$f" --steps "$steps" --corpus aistpp --joints "$j" --fps "$f"
done; done
# Table 4.6: scratch on AIST++ vs pre-train (all) vs fine-tune on AIST++.
run t46-scratch --steps $((steps + steps / 2)) --corpus aistpp
run t46-pretrain --steps "$steps"
for lr in 1e-3 5e-4; do
  echo "== t46-finetune-$lr"
  "$bin" train --out "$out/t46-finetune-$lr" --init "$out/t46-pretrain" --corpus aistpp \
    --steps $((steps / 2)) --eval-every $((steps / 2)) --batch 8 --lr "$lr" > "$out/t46-finetune-$lr.json" 2> "$out/t46-finetune-$lr.log"
done
"$bin" eval --checkpoint "$out/t46-pretrain" --corpus aistpp > "$out/t46-pretrain-on-aistpp.json"
echo done
