#!/usr/bin/env bash
# Prepares the third-party peers used by tests/bags/bag_interop.rs (bag readers),
# tests/node/cyclone.rs (Cyclone DDS), tests/node/foxglove.rs (Foxglove's WebSocket client) and
# tests/node/fastdds.rs (Fast DDS), tests/node/rosout.rs (Cyclone DDS) and tests/node/rclpy.rs
# (real ROS 2 clients: rclpy of Jazzy and Kilted with rmw_fastrtps_cpp). Idempotent.
#
# Usage: tests/interop/setup.sh DIR
#   - creates a Python venv at DIR/.venv with mcap, mcap-ros2-support, rosbags and cyclonedds
#     (its wheel bundles the Cyclone DDS C library)
#     (skipped when it already imports them);
#   - runs `npm install` (from package.json / package-lock.json) into tests/interop
#     (skipped when node_modules already holds the pinned packages);
#   - installs Debian's libfastrtps-dev, libfastcdr-dev, fastddsgen and g++ with apt-get
#     (skipped when dpkg has them; needs root otherwise) and builds the Fast DDS peer
#     tests/interop/fastdds into DIR/.fastdds-peer (skipped when up to date);
#   - creates DIR/.venv-rclpy-jazzy and DIR/.venv-rclpy-kilted with that distribution's rclpy,
#     rmw_fastrtps_cpp and message wheels from the Python package index (Python 3.11; skipped
#     when they import).
# Then export, as printed at the end:
#   MODE360_PYTHON=DIR/.venv/bin/python  MODE360_NODE_DIR=<repo>/tests/interop
#   MODE360_FASTDDS_PEER=DIR/.fastdds-peer/fastdds_peer
#   MODE360_RCLPY_JAZZY=DIR/.venv-rclpy-jazzy/bin/python
#   MODE360_RCLPY_KILTED=DIR/.venv-rclpy-kilted/bin/python
set -euo pipefail

if [[ $# -ne 1 ]]; then
  echo "usage: $0 DIR   (the venv goes to DIR/.venv)" >&2
  exit 2
fi
root="$(cd "$1" && pwd)"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$root/.venv"
python="$venv/bin/python"
# Pinned to the versions the checks were written against.
python_packages=(mcap==1.6.0 mcap-ros2-support==0.6.0 rosbags==0.11.9 cyclonedds==11.0.1)

if [[ -x "$python" ]] && "$python" -c "import mcap, mcap_ros2, rosbags, cyclonedds" 2>/dev/null; then
  echo "python: $venv already has ${python_packages[*]}"
else
  if [[ ! -x "$python" ]]; then
    echo "python: creating venv $venv"
    python3 -m venv "$venv"
  fi
  echo "python: installing ${python_packages[*]} into $venv"
  "$python" -m pip install --quiet --upgrade "${python_packages[@]}"
fi

node_packages=(@mcap/core @foxglove/rosmsg @foxglove/rosmsg2-serialization @foxglove/ws-protocol ws)
have_all=1
for p in "${node_packages[@]}"; do
  [[ -f "$here/node_modules/$p/package.json" ]] || have_all=0
done
if [[ $have_all -eq 1 ]]; then
  echo "node: $here/node_modules already has ${node_packages[*]}"
else
  echo "node: npm install in $here"
  if [[ -f "$here/package-lock.json" ]]; then
    (cd "$here" && npm ci --no-audit --no-fund)
  else
    (cd "$here" && npm install --no-audit --no-fund)
  fi
fi

# Fast DDS 2.9 (Debian bookworm) and its IDL code generator.
apt_packages=(libfastrtps-dev libfastcdr-dev fastddsgen g++)
missing=()
for p in "${apt_packages[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [[ ${#missing[@]} -eq 0 ]]; then
  echo "fastdds: dpkg already has ${apt_packages[*]}"
else
  echo "fastdds: apt-get install ${missing[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
fastdds_peer="$(bash "$here/fastdds/build.sh" "$root/.fastdds-peer" | tail -n 1)"

# Real ROS 2 clients: the rclpy wheels of each distribution, in a venv of its own.
for distro in jazzy kilted; do
  rvenv="$root/.venv-rclpy-$distro"
  rpython="$rvenv/bin/python"
  if [[ -x "$rpython" ]] && "$rpython" -c "import rclpy, rmw_fastrtps_cpp, sensor_msgs.msg, rcl_interfaces.srv" 2>/dev/null; then
    echo "rclpy: $rvenv already has rclpy ($distro)"
  else
    [[ -x "$rpython" ]] || python3 -m venv "$rvenv"
    echo "rclpy: installing the ros-$distro wheels into $rvenv"
    "$rpython" -m pip install --quiet "ros-$distro-rclpy" "ros-$distro-rmw-fastrtps-cpp" \
      "ros-$distro-sensor-msgs" "ros-$distro-rcl-interfaces" "ros-$distro-diagnostic-msgs"
  fi
done

echo "export MODE360_PYTHON=$python"
echo "export MODE360_NODE_DIR=$here"
echo "export MODE360_FASTDDS_PEER=$fastdds_peer"
echo "export MODE360_RCLPY_JAZZY=$root/.venv-rclpy-jazzy/bin/python"
echo "export MODE360_RCLPY_KILTED=$root/.venv-rclpy-kilted/bin/python"
