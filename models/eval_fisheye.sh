#!/usr/bin/env bash
# The fisheye rows of the model card (issue 12): 8 held-out frames of varied streets (world seed
# 9001, frames 50 to 57, never a training world: training seeds are drawn by the data stream)
# rendered on the Deep360 rig, the OmniMVS-like rig and the dual-fisheye rig at 256 wide, clean,
# then each estimator with its geometry share (true views minus same-image views).
#   models/eval_fisheye.sh [WEIGHTS] [OUT_DIR]
set -euo pipefail
bin="${MODE360_BIN:-target/release/mode360}"
weights="${1:-models/ssmode_parallax_zncc_log.safetensors}"
out="${2:-eval_fisheye}"
mkdir -p "$out"
for rig in deep360 omnimvs dual_fisheye; do
  bag="$out/heldout_$rig.mcap"
  [[ -f "$bag" ]] || "$bin" synth --rig "launch_configs/rig_$rig.yaml" --frames 8 --first-frame 50 \
    --width 256 --seed 9001 --street varied --out "$bag"
  "$bin" eval --bag "$bag" --estimator photometric --geometry-share --json "$out/photometric_$rig.json"
  "$bin" eval --bag "$bag" --estimator ssmode --weights "$weights" --geometry-share \
    --json "$out/ssmode_$rig.json"
done
