#!/usr/bin/env bash
# The node's resident memory with N Foxglove clients that never read (issue 22): 30 s without
# a client, 120 s with N stalled clients (tests/interop/stall_clients.mjs), 40 s after they
# left, while a bag plays in a loop. Manual benchmark, not run by CI.
#   MODE360_NODE_DIR=DIR [N=5] [BIN=target/release/mode360] tests/interop/live_view_memory.sh
set -u
cd "$(dirname "$0")/../.."
export ROS_DOMAIN_ID=93 MODE360_NODE_DIR="${MODE360_NODE_DIR:-tests/interop}"
N=${N:-5}
${BIN:-target/release/mode360} node --ros-args -p foxglove_port:=8799 -p output_width:=256 > /tmp/livenode.log 2>&1 &
NODE=$!
sleep 3
${BIN:-target/release/mode360} play bags/demo_deep360.mcap --loop > /tmp/liveplay.log 2>&1 &
PLAY=$!
rss() { awk '/VmRSS/ {print $2/1024}' /proc/$NODE/status; }
t0=$(date +%s)
for i in 1 2 3; do sleep 10; echo "t=$(( $(date +%s)-t0 )) s rss=$(rss) MiB (no client)"; done
node tests/interop/stall_clients.mjs ws://127.0.0.1:8799 $N 120 > /tmp/stall.log 2>&1 &
CL=$!
for i in $(seq 1 12); do sleep 10; echo "t=$(( $(date +%s)-t0 )) s rss=$(rss) MiB ($N stalled clients)"; done
wait $CL
for i in 1 2 3 4; do sleep 10; echo "t=$(( $(date +%s)-t0 )) s rss=$(rss) MiB (clients gone)"; done
kill -INT $PLAY; kill -INT $NODE; wait
head -3 /tmp/stall.log
