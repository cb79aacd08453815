#!/usr/bin/env bash
# Issue 19's training on a lent GPU: one call of the `device` tool, from the repository root
# there, within its 10-minute command limit:
#
#   run(command="bash models/train_gpu.sh", carry=["target-cuda/dist"], timeout_s=600)
#
# It needs target-cuda/dist/mode360.xz, the cuda build packed small enough to travel (the tree
# plus what is carried must stay under 64 MiB):
#
#   scripts/build_cuda.sh && mkdir -p target-cuda/dist &&
#     strip -o target-cuda/dist/mode360 target-cuda/release/mode360 &&
#     xz -T2 -6 -f target-cuda/dist/mode360
#
# Then, on the GPU machine (its PyTorch provides CUDA 13's libraries, its driver libcuda):
#   1. unpacks the binary, finds the libraries, prints the GPU;
#   2. the CUDA table kernels checked against the CPU's and a training step timed by part
#      (target-cuda/dist/train_step_profile.xz, the example of that name, when carried);
#   3. `bench-model` of the standing weights on cuda:0 at 256 and 512 -> $OUT/bench_gpu.json
#      (BENCH=0 leaves it out);
#   4. a short probe of the fine-tune for its time per step, then the fine-tune proper: the
#      latest standing checkpoint at 256 (runs/standing_w256_ship/checkpoint, else the
#      shipped weights' source, runs/gpu_w256/) at width 256 with the standing job's data mix, as many steps as fit before the deadline, so that the cosine schedule
#      ends there -> $OUT: the weights, state.json, train.csv, val.csv, curves.png.
# Each stage is bounded by `timeout`, and a failed stage leaves the later ones to run, so one
# call always brings back what it could measure.
#
# env: BUDGET_S (seconds from start to the end of the fine-tune, 540), INIT (start weights,
# as in 4; the eighth session's call started from the 128 stage's runs/standing/checkpoint),
# WIDTH (256), LR (1e-4), MAX_STEPS (6000),
# DEVICE (cuda:0), BIN (a binary to use instead of unpacking one: a dry run here takes
# BIN=target/release/mode360 DEVICE=cpu WIDTH=128 BUDGET_S=150 OUT=/tmp/dry)
set -uo pipefail
start=$(date +%s)
budget_s="${BUDGET_S:-540}"
deadline=$((start + budget_s))
init="${INIT:-runs/clutter_weighted/checkpoint/model.safetensors}"
[[ -f "$init" ]] || init=models/ssmode_parallax_zncc_log.safetensors
width="${WIDTH:-256}"
lr="${LR:-1e-4}"
max_steps="${MAX_STEPS:-6000}"
device="${DEVICE:-cuda:0}"
out="${OUT:-/tmp/train_gpu_out}"
mkdir -p "$out"
log="$out/train_gpu.log"
exec > >(tee -a "$log") 2>&1
say() { echo "[$(($(date +%s) - start)) s] $*"; }

# 1. The binary and CUDA's libraries.
bin="${BIN:-/tmp/mode360-cuda}"
if [[ -z "${BIN:-}" ]]; then
  xz -dc target-cuda/dist/mode360.xz >"$bin" && chmod +x "$bin" || {
    say "no target-cuda/dist/mode360.xz to unpack"
    exit 1
  }
fi
libdir="$(python3 -c 'import os, nvidia; print(os.path.join(list(nvidia.__path__)[0], "cu13", "lib"))' 2>/dev/null)"
if [[ ! -d "$libdir" ]]; then
  libdir="$(dirname "$(find / -name 'libcublas.so.13' -not -path '/proc/*' 2>/dev/null | head -1)")"
fi
export LD_LIBRARY_PATH="$libdir${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
say "CUDA libraries: $libdir ($(ls "$libdir" 2>/dev/null | tr '\n' ' '))"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
say "cpus: $(nproc)"
ldd "$bin" | grep -E "not found|cuda|cublas|curand|nvrtc" || true

# 2. The CUDA table kernels against the CPU's, and a training step by part (3 steps at WIDTH).
if [[ -f target-cuda/dist/train_step_profile.xz ]]; then
  xz -dc target-cuda/dist/train_step_profile.xz >/tmp/train_step_profile && chmod +x /tmp/train_step_profile
  timeout 120 /tmp/train_step_profile parallax_zncc_log 3 "$device" "$width"
  status=$?
  say "train_step_profile exit $status"
  if ((status != 0)); then
    say "the GPU's training path failed its check: no fine-tune"
    exit 1
  fi
fi

# 3. The network's speed on the GPU (BENCH=0 leaves it out).
[[ "${BENCH:-1}" == 0 ]] || timeout 100 "$bin" bench-model --presets parallax_zncc_log --widths 256,512 --runs 5 \
  --weights "$init" --device "$device" --json "$out/bench_gpu.json"
say "bench-model exit $?"

mix=(--objects-fraction 0.25 --street varied --soiled-fraction 0.3 --fisheye-fraction 0.2
  --rig-layouts any --blocked-fraction 0.2 --max-grad-norm 50 --rig-pool 6)
train=("$bin" train --device "$device" --preset parallax_zncc_log --width "$width" --lr "$lr"
  --init-weights "$init" "${mix[@]}")

# 4a. Probe: seconds per step once the rig pool's tables are built (median of the last half).
probe_steps=16
timeout 150 "${train[@]}" --steps "$probe_steps" --warmup-steps 4 --val-every 100000 \
  --checkpoint-every 100000 --out /tmp/probe
say "probe exit $?"
cp /tmp/probe/train.csv "$out/probe_train.csv" 2>/dev/null
step_s="$(python3 - <<'EOF'
import csv, statistics
try:
    rows = list(csv.DictReader(open("/tmp/probe/train.csv")))
    s = [float(r["step_s"]) for r in rows[len(rows) // 2:]]
    print(f"{statistics.median(s):.3f}" if s else "")
except Exception:
    print("")
EOF
)"
if [[ -z "$step_s" ]]; then
  say "the probe trained no step: no fine-tune"
  exit 1
fi
# time left, less the validation passes (one per 250 steps plus the last) and the final save
left=$((deadline - $(date +%s) - 40))
steps="$(python3 -c "print(max(0, min($max_steps, int($left / ($step_s * 1.08)))))")"
say "probe: $step_s s per step; fine-tune of $steps steps in the $left s left"
if ((steps < 50)); then
  say "too little time left to fine-tune"
  exit 1
fi

# 4b. The fine-tune, the schedule fitted to the time left; a hard stop 20 s before the end.
run=/tmp/gpu_w$width
timeout $((deadline - $(date +%s) + 20)) "${train[@]}" --steps "$steps" \
  --warmup-steps $((steps / 20 + 1)) --val-every 250 --checkpoint-every 100 --out "$run"
say "fine-tune exit $?"
for f in ssmode_parallax_zncc_log.safetensors train.csv val.csv curves.png; do
  cp "$run/$f" "$out/" 2>/dev/null
done
[[ -f "$out/ssmode_parallax_zncc_log.safetensors" ]] ||
  cp "$run/checkpoint/model.safetensors" "$out/checkpoint_model.safetensors" 2>/dev/null
cp "$run/checkpoint/state.json" "$out/state.json" 2>/dev/null
tail -3 "$run/train.csv" "$run/val.csv" 2>/dev/null
say "done"
