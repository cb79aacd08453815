#!/usr/bin/env bash
# Scores SSMODE weights and the photometric sweep on the evaluation set at 256 that
# tools/make_eval_bags.sh renders (models/README.md, "The evaluation set at 256"): the Deep360
# rig with 4, 3 and 2 cameras and the unseen trapezoid rig with 4, clean and soiled rows each.
# Every run is the geometry check too: `eval --geometry-share` scores the true views, then the
# reference camera's image on every camera, and reports δ1(true) − δ1(same image) per condition.
# Writes per run NAME.json (true_views, same_image, geometry_share) and NAME.txt (both tables and
# the share) to OUT_DIR, and all shares to OUT_DIR/geometry_share.md.
#
#   tools/evaluate.sh [BAGS_DIR] [OUT_DIR] [WEIGHTS]
#     BAGS_DIR  the bags of tools/make_eval_bags.sh (/tmp/mode360_eval)
#     OUT_DIR   results (/tmp/mode360_eval_out)
#     WEIGHTS   SSMODE weights (models/ssmode_parallax_zncc_log_fine.safetensors)
#
# env (default): ESTIMATORS ("ssmode photometric"), GEOMETRY_SHARE (1; 0 skips the same-image
# pass, half the time), MODE360_BIN (target/release/mode360). Relative defaults are taken from
# the repository root, so the script runs from any folder.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bags="${1:-/tmp/mode360_eval}"
out="${2:-/tmp/mode360_eval_out}"
weights="${3:-$root/models/ssmode_parallax_zncc_log_fine.safetensors}"
bin="${MODE360_BIN:-$root/target/release/mode360}"
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
