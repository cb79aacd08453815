#!/usr/bin/env bash
# Trains the multi-view `parallax` SSMODE in four stages, resuming whichever stage is unfinished
# (run it in the background at the start of every session; it picks up where the last one
# stopped, and each stage checks its own options on resume):
#   1. runs/parallax_objects_w128: random objects only, at width 128 (matching, coarse and cheap)
#   2. runs/parallax_streets_w128: varied streets (30 % soiled) with a quarter of objects, still at
#      width 128 (about 1 s a step on 2 cores), initialised from stage 1's final weights
#   3. runs/parallax_streets: the same mix at the shipped width 256 (about 4 s a step),
#      initialised from stage 2's final weights, at half the learning rate
#   4. runs/parallax_fisheye: the same mix at 256 with half of the rendered samples on random
#      fisheye and dual-fisheye racks (issue 12), initialised from stage 3's final weights
# Then copy runs/parallax_fisheye/ssmode_parallax.safetensors to models/ and evaluate it
# (tools/make_eval_bags.sh and tools/evaluate.sh, tools/eval_fisheye.sh).
#   models/train_parallax.sh [STAGE1_STEPS] [STAGE2_STEPS] [STAGE3_STEPS] [STAGE4_STEPS]
set -euo pipefail
bin="${MODE360_BIN:-target/release/mode360}"
s1="${1:-3000}"
s2="${2:-1800}"
s3="${3:-1000}"
s4="${4:-500}"
"$bin" train --preset parallax --width 128 --steps "$s1" --lr 2e-4 --objects-fraction 1 \
  --val-every 250 --checkpoint-every 100 --out runs/parallax_objects_w128 --resume
streets=(--objects-fraction 0.25 --street varied --soiled-fraction 0.3 --max-grad-norm 50
  --val-every 250 --checkpoint-every 100 --resume)
"$bin" train --preset parallax --width 128 --steps "$s2" --lr 2e-4 "${streets[@]}" \
  --init-weights runs/parallax_objects_w128/ssmode_parallax.safetensors \
  --out runs/parallax_streets_w128
"$bin" train --preset parallax --steps "$s3" --lr 1e-4 "${streets[@]}" \
  --init-weights runs/parallax_streets_w128/ssmode_parallax.safetensors \
  --out runs/parallax_streets
"$bin" train --preset parallax --steps "$s4" --lr 1e-4 --fisheye-fraction 0.5 "${streets[@]}" \
  --init-weights runs/parallax_streets/ssmode_parallax.safetensors \
  --out runs/parallax_fisheye
