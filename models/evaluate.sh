#!/usr/bin/env bash
# Scores the shipped SSMODE weights (parallax; pass WEIGHTS for others) and the photometric sweep on the held-out set rendered by
# models/make_eval_bags.sh: Deep360 rig with 4, 3 and 2 cameras, and the unseen trapezoid rig
# with 4 cameras; clean and soiled rows each. Every run is the geometry check too (design.md):
# `eval --geometry-share` scores true views, then the reference camera's image on every camera,
# and reports δ1(true) − δ1(same image) per condition. Writes per run NAME.json (true_views,
# same_image, geometry_share) and NAME.txt (both tables and the share) to OUT, and all shares
# in OUT/geometry_share.md. GEOMETRY_SHARE=0 skips the same-image pass (half the time).
#   models/evaluate.sh [BAGS_DIR] [OUT_DIR] [WEIGHTS]
set -euo pipefail
bags="${1:-/tmp/mode360_eval}"
out="${2:-/tmp/mode360_eval_out}"
weights="${3:-models/ssmode_parallax_zncc_log.safetensors}"
bin="${MODE360_BIN:-target/release/mode360}"
estimators="${ESTIMATORS:-ssmode photometric}"
share=(--geometry-share); [[ ${GEOMETRY_SHARE:-1} == 0 ]] && share=()
mkdir -p "$out"
summary="$out/geometry_share.md"
if [[ ${#share[@]} -gt 0 ]]; then
  printf '%s\n%s\n' "| estimator | rig | cameras | condition | frames | δ1 true % | δ1 same image % | geometry share (points) |" \
    "|---|---|---|---|---|---|---|---|" >"$summary"
fi
args() { for k in 1 2 3 4 5; do echo "--bag $bags/${1}_clean_$k.mcap --bag $bags/${1}_soiled_$k.mcap"; done; }
for est in $estimators; do
  w=(); [[ $est == ssmode ]] && w=(--weights "$weights")
  for case in "deep360 1,2,3,4" "deep360 1,2,3" "deep360 1,2" "trapezoid 1,2,3,4"; do
    set -- $case
    name="${est}_${1}_$(echo "$2" | tr -cd ',' | wc -c | xargs -I{} expr {} + 1)cam"
    # shellcheck disable=SC2046
    "$bin" eval --estimator "$est" "${w[@]}" "${share[@]}" $(args "$1") --cameras "$2" \
      --json "$out/$name.json" | tee "$out/$name.txt"
    if [[ ${#share[@]} -gt 0 ]]; then
      sed -n '/^geometry share/,$p' "$out/$name.txt" | grep -E '^\| (clean|soiled) ' |
        sed "s/^|/| $est | $1 | $2 |/" >>"$summary"
    fi
  done
done
[[ ${#share[@]} -gt 0 ]] && cat "$summary"
exit 0
