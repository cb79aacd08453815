#!/usr/bin/env bash
# Issue 19's standing training job: start it in the background at the beginning of every
# session while the issue is open; it resumes runs/standing/ where the last session stopped
# (checkpoint every 250 steps and every 5 minutes, so a stopped session loses little), and
# commit runs/standing/{checkpoint,train.csv,val.csv,curves.png} every half hour or so.
#
#   nohup nice -n 10 models/train_standing.sh > /tmp/standing.log 2>&1 &
#
# The run: preset parallax_zncc_log (the ablation's winner, models/README.md) at width 128 (the
# cheap width; the deployable weights get a short fine-tune at 256, see below), one rendered
# sample per step, towards the paper's budget of about 115,000 steps (the cosine schedule runs
# over that, so the learning rate stays near its peak for many sessions). The data: varied
# streets with a quarter of random objects, 30 % soiled, a fifth of the samples on fisheye
# racks, every rig layout (roof racks, vertical masts, turned cameras at mixed heights, car
# body corners), a fifth with one lens 5 to 40 % blocked, and random rigs from a pool of 16
# renewed every 400 samples, so that sweep tables are built once per pool rig, not per step.
# It started from the ablation's parallax_zncc_log weights at step 500 (a fresh run of this
# script needs them at INIT).
#
# With a second argument `fine-tune`, it instead fine-tunes the latest standing weights at
# width 256 for W256_STEPS steps into runs/standing_w256/ (fresh each time; a rig pool of 6, as
# sweep tables at 256 take about 0.8 GiB per rig with their transposes): the weights to
# evaluate and ship (training at 128 alone costs accuracy at 256, models/README.md).
# A session with a GPU runs the same fine-tune there instead, about 1,000 steps in one device call
# (models/train_gpu.sh; 0.56 s per step on an H200 against about 5 s here).
#
# env: MODE360_BIN (target/release/mode360), INIT (start weights of a fresh run),
# STEPS (115000), W256_STEPS (300)
set -euo pipefail
bin="${MODE360_BIN:-target/release/mode360}"
init="${INIT:-runs/ablation/parallax_zncc_log/ssmode_parallax_zncc_log_step500.safetensors}"
steps="${STEPS:-115000}"
mix=(--objects-fraction 0.25 --street varied --soiled-fraction 0.3 --fisheye-fraction 0.2
  --rig-layouts any --blocked-fraction 0.2 --max-grad-norm 50)
if [[ "${1:-}" == fine-tune ]]; then
  rm -rf runs/standing_w256
  exec "$bin" train --preset parallax_zncc_log --width 256 --steps "${W256_STEPS:-300}" --lr 1e-4 \
    --warmup-steps 50 "${mix[@]}" --rig-pool 6 --val-every 100 --checkpoint-every 50 \
    --init-weights runs/standing/checkpoint/model.safetensors --out runs/standing_w256
fi
exec "$bin" train --preset parallax_zncc_log --width 128 --steps "$steps" --lr 2e-4 \
  --warmup-steps 100 "${mix[@]}" --rig-pool 16 --val-every 500 --checkpoint-every 250 --resume \
  --init-weights "$init" --out runs/standing
