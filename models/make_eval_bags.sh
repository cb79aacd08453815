#!/usr/bin/env bash
# Renders the held-out evaluation set of models/README.md into DIR (default /tmp/mode360_eval):
# 5 worlds x 20 frames, clean and soiled, on the Deep360 rig and on the unseen trapezoid rig, at
# the compact preset's 256x128. World seeds have the top bit set (2^63 + k): training draws its
# worlds with that bit clear, so no evaluation world was ever trained on.
set -euo pipefail
out="${1:-/tmp/mode360_eval}"
bin="${MODE360_BIN:-target/release/mode360}"
mkdir -p "$out"
for k in 1 2 3 4 5; do
  seed=$(python3 -c "print(2**63 + $k)")
  for rig in deep360:launch_configs/rig_deep360.yaml trapezoid:models/eval_rigs/rig_trapezoid.yaml; do
    name="${rig%%:*}"; path="${rig#*:}"
    "$bin" synth --rig "$path" --frames 20 --first-frame $((40 * k)) --width 256 --seed "$seed" \
      --out "$out/${name}_clean_$k.mcap"
    "$bin" synth --rig "$path" --frames 20 --first-frame $((40 * k)) --width 256 --seed "$seed" \
      --soiled --out "$out/${name}_soiled_$k.mcap"
  done
done
ls -la "$out"
