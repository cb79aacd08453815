#!/usr/bin/env bash
# Builds the Fast DDS peer of tests/node/fastdds.rs into BUILD_DIR: fastddsgen generates the
# type support for Ros2Msgs.idl into BUILD_DIR/gen, then g++ compiles it with fastdds_peer.cpp
# against Debian's libfastrtps-dev / libfastcdr-dev. Skipped when BUILD_DIR/fastdds_peer is
# newer than every source.
#
# Usage: tests/interop/fastdds/build.sh BUILD_DIR    (prints the peer's path last)
set -euo pipefail

if [[ $# -ne 1 ]]; then
  echo "usage: $0 BUILD_DIR" >&2
  exit 2
fi
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
mkdir -p "$1"
build="$(cd "$1" && pwd)"
peer="$build/fastdds_peer"
sources=("$here/Ros2Msgs.idl" "$here/fastdds_peer.cpp" "$here/build.sh")

up_to_date=1
[[ -x "$peer" ]] || up_to_date=0
for s in "${sources[@]}"; do
  [[ $up_to_date -eq 1 && "$s" -nt "$peer" ]] && up_to_date=0
done
if [[ $up_to_date -eq 1 ]]; then
  echo "fastdds: $peer is up to date"
else
  echo "fastdds: generating type support with fastddsgen into $build/gen"
  rm -rf "$build/gen"
  mkdir -p "$build/gen"
  fastddsgen -replace -d "$build/gen" "$here/Ros2Msgs.idl" >/dev/null
  echo "fastdds: compiling $peer"
  g++ -std=c++17 -O2 -Wall -Wextra -I "$build/gen" \
    "$here/fastdds_peer.cpp" "$build/gen/Ros2Msgs.cxx" "$build/gen/Ros2MsgsPubSubTypes.cxx" \
    -lfastrtps -lfastcdr -o "$peer.tmp"
  mv "$peer.tmp" "$peer"
fi
echo "$peer"
