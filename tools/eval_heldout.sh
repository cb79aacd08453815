#!/usr/bin/env bash
# The held-out rows of models/README.md, rendered from a world training never uses (seed
# 2^63 + 19: training draws its worlds with the top bit clear), FRAMES frames from FIRST_FRAME,
# at WIDTH:
#   streets_clean     streets on the Deep360 rig
#   streets_soiled    the same frames with lens soiling (--soiled)
#   objects           random objects all around the Deep360 rig (--scene objects)
#   vertical_pair     EVAL_RIGS/rig_vertical_pair.yaml (two cameras 0.3 m apart vertically)
#   turned3           EVAL_RIGS/rig_turned3.yaml (three cameras turned, at two heights)
#   omnimvs           RIGS/rig_omnimvs.yaml (fisheyes scaled by WIDTH / 512)
#   blocked_third     the Deep360 rig with camera 3's lens one third blocked by mud
#   cluttered         cluttered streets (near clutter from about 0.7 m out) on the Deep360 rig
#   cluttered_soiled  the same frames with lens soiling
# then every estimator of ESTIMATORS with `mode360 eval --geometry-share` (true views, then the
# reference image on every camera), and one markdown table in OUT/summary.md: row, estimator,
# δ1 true, δ1 same image, geometry share (points), AbsRel, and the obstacle metrics of
# docs/ground_truth.md (recall per band and thin, δ1 over object pixels within 5 m, phantom free
# space and its out-of-range part; n/a where a row has no labelled obstacle). Bags are named
# after WIDTH and FRAMES (and SEED, FIRST_FRAME when set) and rendered only when missing.
#
#   tools/eval_heldout.sh [BAGS_DIR]      BAGS_DIR: where bags are rendered (/tmp/mode360_heldout)
#
# env (default):
#   ROWS         rows to run, by name, space separated (all of the above)
#   SEED         world seed (2^63 + 19); another top-bit seed gives a validation set for tuning a
#                readout, never the held-out rows: SEED=$(python3 -c 'print(2**63 + 3131)')
#   WIDTH        panorama width (512); FRAMES (4); FIRST_FRAME (60)
#   ESTIMATORS   ("ssmode photometric"; also psmode)
#   WEIGHTS      SSMODE weights (models/ssmode_parallax_zncc_log_fine.safetensors); when set, also
#                PSMODE's stage 1 (unset: PSMODE's own, models/psmode_stage1.safetensors)
#   FUSION       PSMODE's fusion weights, or none (the most confident pair) (unset: consensus, the
#                range the pairs agree on)
#   PAIR_WIDTH   PSMODE's stage-1 width (unset: the default, 512; 0: its trained width, 256)
#   NEAR_PASS    SSMODE's near-pass width (unset: off)
#   NEAR_PASS_SOURCE  what the near pass is: network or sweep (network)
#   NEAR_MODE    SSMODE's near-mode probability (unset: the default, 0.2; above 1: off)
#   OUT          output folder (BAGS_DIR/out)
#   MODE360_BIN  the binary (target/release/mode360)
#   RIGS         folder of the shipped rigs (launch_configs)
#   EVAL_RIGS    folder of the evaluation-only rigs (models/eval_rigs)
# Relative defaults are taken from the repository root, so the script runs from any folder.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bags="${1:-/tmp/mode360_heldout}"
out="${OUT:-$bags/out}"
width="${WIDTH:-512}"
frames="${FRAMES:-4}"
first="${FIRST_FRAME:-60}"
estimators="${ESTIMATORS:-ssmode photometric}"
weights="${WEIGHTS:-$root/models/ssmode_parallax_zncc_log_fine.safetensors}"
bin="${MODE360_BIN:-$root/target/release/mode360}"
rigs="${RIGS:-$root/launch_configs}"
eval_rigs="${EVAL_RIGS:-$root/models/eval_rigs}"
seed="${SEED:-$(python3 -c "print(2**63 + 19)")}"
fisheye_scale=$(python3 -c "print($width / 512)")
deep360=$rigs/rig_deep360.yaml
mkdir -p "$bags" "$out"

rows=(
  "streets_clean|--rig $deep360"
  "streets_soiled|--rig $deep360 --soiled"
  "objects|--rig $deep360 --scene objects"
  "vertical_pair|--rig $eval_rigs/rig_vertical_pair.yaml"
  "turned3|--rig $eval_rigs/rig_turned3.yaml"
  "omnimvs|--rig $rigs/rig_omnimvs.yaml --fisheye-scale $fisheye_scale"
  "blocked_third|--rig $deep360 --blocked-lens 3:0.3333:mud"
  "cluttered|--rig $deep360 --street cluttered"
  "cluttered_soiled|--rig $deep360 --street cluttered --soiled"
)
if [[ -n "${ROWS:-}" ]]; then
  picked=()
  for row in "${rows[@]}"; do
    [[ " $ROWS " == *" ${row%%|*} "* ]] && picked+=("$row")
  done
  rows=("${picked[@]}")
fi

# bags of another seed or first frame than the held-out ones carry them in their name
suffix=""
[[ -n "${SEED:-}" ]] && suffix="_s$seed"
[[ -n "${FIRST_FRAME:-}" ]] && suffix="${suffix}_ff$first"
bag_of() { echo "$bags/${1}_w${width}_f${frames}${suffix}.mcap"; }

for row in "${rows[@]}"; do
  name="${row%%|*}"
  bag=$(bag_of "$name")
  if [[ ! -f "$bag" ]]; then
    # shellcheck disable=SC2086
    "$bin" synth ${row#*|} --frames "$frames" --first-frame "$first" --width "$width" \
      --seed "$seed" --out "$bag"
  fi
done

summary="$out/summary.md"
{
  echo "seed $seed, $frames frame(s) per row at ${width}x$((width / 2)), frames $first.."
  echo
  echo "| row | estimator | δ1 true % | δ1 same image % | geometry share (points) | AbsRel | recall 0-2 m | recall 2-5 m | recall 5-10 m | thin | δ1 objects ≤ 5 m | phantom % | out of range % |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
} >"$summary"
for est in $estimators; do
  w=()
  [[ $est == ssmode || ($est == psmode && -n "${WEIGHTS:-}") ]] && w=(--weights "$weights")
  [[ $est == psmode && -n "${FUSION:-}" ]] && w+=(--fusion-weights "$FUSION")
  [[ $est == psmode && -n "${PAIR_WIDTH:-}" ]] && w+=(--pair-width "$PAIR_WIDTH")
  [[ $est == ssmode && -n "${NEAR_MODE:-}" ]] && w+=(--near-mode-probability "$NEAR_MODE")
  [[ $est == ssmode && -n "${NEAR_PASS:-}" ]] &&
    w+=(--near-pass-width "$NEAR_PASS" --near-pass-source "${NEAR_PASS_SOURCE:-network}")
  for row in "${rows[@]}"; do
    name="${row%%|*}"
    json="$out/${name}_${est}.json"
    "$bin" eval --bag "$(bag_of "$name")" --estimator "$est" "${w[@]}" --geometry-share \
      --json "$json" >"$out/${name}_${est}.txt"
    python3 - "$json" "$name" "$est" >>"$summary" <<'EOF'
import json, sys
path, name, est = sys.argv[1:4]
r = json.load(open(path))
share = r["geometry_share"][0]
row = r["true_views"]["rows"][0]
abs_rel = row["depth"]["abs_rel"]
o = row.get("obstacles")
def pct(v):
    return "n/a" if v is None else f"{v:.1f}"
def recall(b):
    return f"{pct(b['recall_pct'])} ({b['recovered']}/{b['instances']})"
if o:
    m = {s["measure"]: s["pooled_pct"] for s in o["measures"]}
    cells = [recall(b) for b in o["bands"]] + [recall(o["thin"])] + [
        pct(m["near_object_delta1"]), pct(m["phantom"]), pct(m["phantom_out_of_range"])]
else:
    cells = ["n/a"] * 7
print(f"| {name} | {est} | {share['delta1_true_pct']:.2f} | {share['delta1_same_image_pct']:.2f} "
      f"| {share['share_pts']:.2f} | {abs_rel:.4f} | " + " | ".join(cells) + " |")
EOF
  done
done
cat "$summary"
