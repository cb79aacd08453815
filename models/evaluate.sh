#!/usr/bin/env bash
# Scores the shipped SSMODE weights and the photometric sweep on the held-out set rendered by
# models/make_eval_bags.sh: Deep360 rig with 4, 3 and 2 cameras, and the unseen trapezoid rig
# with 4 cameras; clean and soiled rows each. Writes one JSON and one table per run to OUT.
#   models/evaluate.sh [BAGS_DIR] [OUT_DIR] [WEIGHTS]
set -euo pipefail
bags="${1:-/tmp/mode360_eval}"
out="${2:-/tmp/mode360_eval_out}"
weights="${3:-models/ssmode_compact.safetensors}"
bin="${MODE360_BIN:-target/release/mode360}"
estimators="${ESTIMATORS:-ssmode photometric}"
mkdir -p "$out"
args() { for k in 1 2 3 4 5; do echo "--bag $bags/${1}_clean_$k.mcap --bag $bags/${1}_soiled_$k.mcap"; done; }
for est in $estimators; do
  w=(); [[ $est == ssmode ]] && w=(--weights "$weights")
  for case in "deep360 1,2,3,4" "deep360 1,2,3" "deep360 1,2" "trapezoid 1,2,3,4"; do
    set -- $case
    name="${est}_${1}_$(echo "$2" | tr -cd ',' | wc -c | xargs -I{} expr {} + 1)cam"
    # shellcheck disable=SC2046
    "$bin" eval --estimator "$est" "${w[@]}" $(args "$1") --cameras "$2" \
      --json "$out/$name.json" | tee "$out/$name.txt"
  done
done
