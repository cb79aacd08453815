#!/usr/bin/env bash
# Ablation of the standing job's objects fraction at equal steps (issue 19: random objects are
# the row furthest from its target). Both arms fork the same standing checkpoint (weights,
# optimizer moments, step and sample position; `train --fork-from`) and keep every other option
# of models/train_standing.sh's w256 stage, so they differ only in the share of random-objects
# samples; both stop at UNTIL (the schedule still runs over the standing job's 20,000 steps).
# The arms run side by side with one thread each on this 2-core machine.
#   models/ablation_objects.sh FORK_DIR          # e.g. a copy of runs/standing_w256_ship/checkpoint's folder
# env: UNTIL (2000), FRACTIONS ("0.25 0.5"), OUT (runs/ablation_objects_w256), MODE360_BIN
set -euo pipefail
fork="${1:?usage: models/ablation_objects.sh FORK_DIR}"
bin="${MODE360_BIN:-target/release/mode360}"
until="${UNTIL:-2000}"
out="${OUT:-runs/ablation_objects_w256}"
pids=()
for f in ${FRACTIONS:-0.25 0.5}; do
  RAYON_NUM_THREADS=1 CANDLE_NUM_THREADS=1 nice -n 10 "$bin" train --preset parallax_zncc_log \
    --width 256 --steps 20000 --until-step "$until" --lr 5e-5 --warmup-steps 50 \
    --objects-fraction "$f" --street varied --soiled-fraction 0.3 --fisheye-fraction 0.2 \
    --rig-layouts any --blocked-fraction 0.2 --max-grad-norm 50 --rig-pool 6 --val-every 125 \
    --checkpoint-every 50 --resume --seed 2 --fork-from "$fork" --out "$out/objects_$f" \
    >"$out.objects_$f.log" 2>&1 &
  pids+=($!)
done
wait "${pids[@]}"
