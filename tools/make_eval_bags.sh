#!/usr/bin/env bash
# Renders the evaluation set at 256 of models/README.md ("The evaluation set at 256"), which
# tools/evaluate.sh scores: 5 worlds x 20 frames, clean and soiled, on the Deep360 rig and on the
# unseen trapezoid rig, at 256x128. World seeds have the top bit set (2^63 + k): training draws
# its worlds with that bit clear, so no evaluation world was ever trained on.
#
#   tools/make_eval_bags.sh [OUT_DIR]     OUT_DIR: where the bags go (/tmp/mode360_eval)
#
# env (default): MODE360_BIN (target/release/mode360), RIGS (launch_configs: rig_deep360.yaml),
# EVAL_RIGS (models/eval_rigs: rig_trapezoid.yaml). Relative defaults are taken from the
# repository root, so the script runs from any folder.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-/tmp/mode360_eval}"
bin="${MODE360_BIN:-$root/target/release/mode360}"
rigs="${RIGS:-$root/launch_configs}"
eval_rigs="${EVAL_RIGS:-$root/models/eval_rigs}"
mkdir -p "$out"
for k in 1 2 3 4 5; do
  seed=$(python3 -c "print(2**63 + $k)")
  for rig in "deep360:$rigs/rig_deep360.yaml" "trapezoid:$eval_rigs/rig_trapezoid.yaml"; do
    name="${rig%%:*}"; path="${rig#*:}"
    "$bin" synth --rig "$path" --frames 20 --first-frame $((40 * k)) --width 256 --seed "$seed" \
      --out "$out/${name}_clean_$k.mcap"
    "$bin" synth --rig "$path" --frames 20 --first-frame $((40 * k)) --width 256 --seed "$seed" \
      --soiled --out "$out/${name}_soiled_$k.mcap"
  done
done
ls -la "$out"
