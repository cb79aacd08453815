#!/usr/bin/env bash
# The node's own memory (issue 39's target: RSS at 512 over 10 minutes): `mode360 node` as its
# own process, fed by `mode360 play --loop` in another, its VmRSS sampled every half second and
# its VmHWM read at the end. `bench-node` runs the node, the player and the subscribers that
# time the outputs in one process, so its RSS counts all three.
#
#   tools/node_rss.sh [DURATION_S] [OUT_DIR]
#     DURATION_S  how long the node is fed (600)
#     OUT_DIR     the input bag, the logs and rss.csv (/tmp/mode360_node_rss)
#
# env (default): MODE360_BIN (target/release/mode360), WIDTH (512: input and output),
# FRAMES (20: frames of the looped bag), ROS_DOMAIN_ID (77), NODE_ARGS (extra `-p name:=value`
# node parameters). Relative defaults are taken from the repository root.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bin="${MODE360_BIN:-$root/target/release/mode360}"
duration="${1:-600}"
out="${2:-/tmp/mode360_node_rss}"
width="${WIDTH:-512}"
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-77}"
mkdir -p "$out"
bag="$out/input_$width.mcap"
[[ -f "$bag" ]] || "$bin" synth --frames "${FRAMES:-20}" --width "$width" --out "$bag"
# shellcheck disable=SC2086
"$bin" node --ros-args -p output_width:="$width" ${NODE_ARGS:-} > "$out/node.log" 2>&1 &
node=$!
sleep 3
"$bin" play --loop "$bag" > "$out/play.log" 2>&1 &
play=$!
trap 'kill -INT $play $node 2>/dev/null || true' EXIT
echo "t_s,rss_mib" > "$out/rss.csv"
max_kib=0
for ((i = 1; i <= 2 * duration; i++)); do
  rss_kib=$(awk '/VmRSS/{print $2}' "/proc/$node/status" 2>/dev/null || true)
  [[ -z "$rss_kib" ]] && { echo "the node stopped early: $out/node.log" >&2; exit 1; }
  ((rss_kib > max_kib)) && max_kib=$rss_kib
  echo "$((i / 2)).$((5 * (i % 2))),$((rss_kib / 1024))" >> "$out/rss.csv"
  ((i % 120 == 0)) && echo "t=$((i / 2)) s: RSS $((rss_kib / 1024)) MiB, max $((max_kib / 1024)) MiB"
  sleep 0.5
done
echo "node RSS at the end $((rss_kib / 1024)) MiB, max sampled $((max_kib / 1024)) MiB, VmHWM $(($(awk '/VmHWM/{print $2}' "/proc/$node/status") / 1024)) MiB"
kill -INT "$play" "$node"
wait "$node" || true
tail -1 "$out/node.log"
