#!/usr/bin/env bash
# The fisheye rows of models/README.md ("Fisheye and dual-fisheye rigs"): 8 held-out frames of
# varied streets (world seed 9001, frames 50 to 57, never a training world: training seeds are
# drawn by the data stream) rendered on the Deep360 rig, the OmniMVS-like rig and the
# dual-fisheye rig at 256 wide, clean, then the photometric sweep and SSMODE, each with its
# geometry share (true views minus same-image views). Bags are rendered only when missing;
# writes OUT_DIR/heldout_RIG.mcap, photometric_RIG.json and ssmode_RIG.json.
#
#   tools/eval_fisheye.sh [WEIGHTS] [OUT_DIR]
#     WEIGHTS  SSMODE weights (models/ssmode_parallax_zncc_log_fine.safetensors)
#     OUT_DIR  bags and results (/tmp/mode360_fisheye)
#
# env (default): MODE360_BIN (target/release/mode360), RIGS (launch_configs: rig_deep360.yaml,
# rig_omnimvs.yaml, rig_dual_fisheye.yaml). Relative defaults are taken from the repository
# root, so the script runs from any folder.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bin="${MODE360_BIN:-$root/target/release/mode360}"
rigs="${RIGS:-$root/launch_configs}"
weights="${1:-$root/models/ssmode_parallax_zncc_log_fine.safetensors}"
out="${2:-/tmp/mode360_fisheye}"
mkdir -p "$out"
for rig in deep360 omnimvs dual_fisheye; do
  bag="$out/heldout_$rig.mcap"
  [[ -f "$bag" ]] || "$bin" synth --rig "$rigs/rig_$rig.yaml" --frames 8 --first-frame 50 \
    --width 256 --seed 9001 --street varied --out "$bag"
  "$bin" eval --bag "$bag" --estimator photometric --geometry-share --json "$out/photometric_$rig.json"
  "$bin" eval --bag "$bag" --estimator ssmode --weights "$weights" --geometry-share \
    --json "$out/ssmode_$rig.json"
done
