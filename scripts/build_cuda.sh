#!/usr/bin/env bash
# Builds mode360 with the `cuda` feature (SSMODE on NVIDIA GPUs, `--device cuda:N`) on a machine
# without a CUDA install, from PyPI's CUDA wheels:
#   1. pip installs the pinned wheels (nvcc, nvvm, crt, runtime, nvrtc, cublas, curand, cccl
#      headers) of one CUDA release into $MODE360_CUDA_DIR/site-<release>, once;
#   2. gathers them under one CUDA_HOME ($MODE360_CUDA_DIR/cuda-<release>): bin, include, nvvm
#      and a lib64 with the unversioned names the linker asks for;
#   3. builds a link-time stub of libcuda (soname libcuda.so.1, every driver function returning
#      CUDA_ERROR_STUB_LIBRARY), so that the binary links without an NVIDIA driver; at run time
#      the GPU host's driver provides the real libcuda.so.1;
#   4. with MODE360_CUDA_KERNELS=network (the default), runs nvcc through a wrapper that leaves
#      out candle's quantized-model kernels (GGUF matrix products, mixture-of-experts), which
#      SSMODE never calls: their sources are most of the kernel build's time (87 minutes here
#      with them). The wrapper writes an empty PTX module for quantized.cu and a static library
#      of weak stubs for the rest (each aborts with a message if ever called);
#   5. runs cargo with the feature in its own target dir, so the CPU build is never disturbed.
#
# The release must not be newer than the GPU host's driver: candle loads its kernels as PTX,
# which a driver compiles only when it knows the PTX version. Drivers 580.x (seen on the lent
# H100/H200 machines) run CUDA 13.0, so 13.0 is the default; 13.4 needs a 595.x driver or newer.
#
# Usage: scripts/build_cuda.sh                 cargo build --release --bin mode360 --features cuda
#        scripts/build_cuda.sh check --tests   cargo check --tests --features cuda (any cargo args)
# Environment: MODE360_CUDA_RELEASE (13.0 or 13.4; default 13.0), MODE360_CUDA_KERNELS (network
# or all; default network), MODE360_CUDA_DIR (default ~/.cache/mode360-cuda), CUDA_TARGET_DIR
# (default target-cuda in the repository), CUDA_COMPUTE_CAP (default 90: H100/H200; 87 for
# Jetson Orin, 89 for Ada, 80 for A100), PYTHON (default python3), CARGO_BUILD_JOBS as usual.
# Idempotent: a second run reuses the wheels, the CUDA_HOME and the stub, and cargo's build.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
cuda_dir="${MODE360_CUDA_DIR:-$HOME/.cache/mode360-cuda}"
target_dir="${CUDA_TARGET_DIR:-$repo/target-cuda}"
python="${PYTHON:-python3}"
release="${MODE360_CUDA_RELEASE:-13.0}"
kernels="${MODE360_CUDA_KERNELS:-network}"
export CUDA_COMPUTE_CAP="${CUDA_COMPUTE_CAP:-90}"
case "$release" in
13.0)
    # cudarc's bindings for CUDA 13.0, matching the wheels below
    export CUDARC_CUDA_VERSION=13000
    wheels=(
        nvidia-cuda-nvcc==13.0.88
        nvidia-nvvm==13.0.88
        nvidia-cuda-crt==13.0.88
        nvidia-cuda-runtime==13.0.96
        nvidia-cuda-nvrtc==13.0.88
        nvidia-cuda-cccl==13.0.85
        nvidia-cublas==13.0.2.14
        nvidia-curand==10.4.0.35
    )
    ;;
13.4)
    export CUDARC_CUDA_VERSION=13040
    wheels=(
        nvidia-cuda-nvcc==13.4.92
        nvidia-nvvm==13.4.92
        nvidia-cuda-crt==13.4.92
        nvidia-cuda-runtime==13.4.92
        nvidia-cuda-nvrtc==13.4.92
        nvidia-cuda-cccl==13.3.5.0.6
        nvidia-cublas==13.4.3.11
        nvidia-curand==10.4.4.72
    )
    ;;
*)
    echo "MODE360_CUDA_RELEASE=$release: expected 13.0 or 13.4" >&2
    exit 2
    ;;
esac
case "$kernels" in
network | all) ;;
*)
    echo "MODE360_CUDA_KERNELS=$kernels: expected network or all" >&2
    exit 2
    ;;
esac
site="$cuda_dir/site-$release"
cuda_home="$cuda_dir/cuda-$release"
wheel_root="$site/nvidia/cu13"

echo "== mode360 CUDA build"
echo "   wheels:       $site"
echo "   CUDA_HOME:    $cuda_home"
echo "   target dir:   $target_dir"
echo "   release:      CUDA $release, CUDARC_CUDA_VERSION=$CUDARC_CUDA_VERSION"
echo "   compute cap:  $CUDA_COMPUTE_CAP; kernels: $kernels"

# 1. The wheels, once per pinned list.
stamp="$site/.mode360-wheels"
if [[ ! -f "$stamp" || "$(cat "$stamp")" != "${wheels[*]}" ]]; then
    echo "== installing ${wheels[*]}"
    mkdir -p "$site"
    "$python" -m pip install --quiet --no-deps --upgrade --target "$site" "${wheels[@]}"
    echo "${wheels[*]}" >"$stamp"
else
    echo "== wheels already installed"
fi

# 2. One CUDA_HOME. nvcc finds include/, include/cccl and nvvm/ relative to its own bin/.
mkdir -p "$cuda_home/lib64"
for part in bin include nvvm; do
    ln -sfn "$wheel_root/$part" "$cuda_home/$part"
done
for lib in "$wheel_root"/lib/*.so.*; do
    name="$(basename "$lib")"
    ln -sfn "$lib" "$cuda_home/lib64/$name"
    # libcublas.so.13 -> libcublas.so (what -lcublas looks for)
    ln -sfn "$lib" "$cuda_home/lib64/${name%%.so.*}.so"
done

# 3. libcuda: always linked against a stub (as NVIDIA's own toolkit does), so the build needs no
#    driver; its soname is libcuda.so.1, which the GPU host's driver provides at run time.
stub="$cuda_home/lib64/stubs/libcuda.so"
if [[ ! -f "$stub" ]]; then
    echo "== libcuda: building a link-time stub from cuda.h"
    mkdir -p "$(dirname "$stub")"
    stub_c="${stub%.so}_stub.c"
    {
        echo "/* Link-time stub of libcuda.so.1 (generated by scripts/build_cuda.sh). */"
        echo "#define CUDA_ERROR_STUB_LIBRARY 34"
        # the names as declared and as cuda.h's macros version them (cuMemAlloc -> cuMemAlloc_v2)
        {
            grep -ohE '^CUresult CUDAAPI cu[A-Za-z0-9_]+' "$wheel_root/include/cuda.h" | awk '{print $3}'
            gcc -E -P -I"$wheel_root/include" "$wheel_root/include/cuda.h" |
                grep -ohE '\bCUresult +cu[A-Za-z0-9_]+ *\(' | sed -E 's/CUresult +//; s/ *\($//'
        } | sort -u | sed 's/.*/int &(void) { return CUDA_ERROR_STUB_LIBRARY; }/'
    } >"$stub_c"
    gcc -shared -fPIC -Wl,-soname,libcuda.so.1 -o "$stub" "$stub_c"
    echo "   $(grep -c '^int ' "$stub_c") functions"
else
    echo "== libcuda: the link-time stub built before ($stub)"
fi

export CUDA_HOME="$cuda_home"
export PATH="$cuda_home/bin:$PATH"
# libcublas.so needs libcublasLt.so.13: GNU ld looks for a library's needs on LD_LIBRARY_PATH
# (set here rather than an -rpath-link in RUSTFLAGS, which would rebuild every crate)
export LD_LIBRARY_PATH="$cuda_home/lib64${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
echo "== $(nvcc --version | grep release)"

# 4. The nvcc wrapper that leaves out the quantized-model kernels.
if [[ "$kernels" == network ]]; then
    kernels_version="$(grep -A1 '^name = "candle-kernels"$' "$repo/Cargo.lock" | sed -n 's/^version = "\(.*\)"$/\1/p')"
    ffi="$(find "${CARGO_HOME:-$HOME/.cargo}/registry/src" -path "*/candle-kernels-$kernels_version/src/ffi.rs" | head -1)"
    if [[ -z "$ffi" ]]; then
        echo "candle-kernels' src/ffi.rs not found under the cargo registry: run cargo fetch first" >&2
        exit 1
    fi
    stubs_c="$cuda_home/candle_quantized_stubs.c"
    {
        echo "/* Weak stubs of candle's quantized-model kernels (scripts/build_cuda.sh). */"
        echo "#include <stdio.h>"
        echo "#include <stdlib.h>"
        grep -oE 'pub fn [A-Za-z0-9_]+' "$ffi" | awk '{print $3}' | sort -u |
            sed 's/.*/__attribute__((weak)) void &(void) { fprintf(stderr, "mode360: & was left out of this CUDA build (MODE360_CUDA_KERNELS=network)\\n"); abort(); }/'
    } >"$stubs_c"
    export MODE360_REAL_NVCC="$cuda_home/bin/nvcc" MODE360_QUANTIZED_STUBS="$stubs_c"
    export NVCC="$repo/scripts/nvcc_network.sh"
    echo "== nvcc through scripts/nvcc_network.sh (quantized-model kernels left out)"
fi

# 5. cargo, with the feature, in its own target dir.
args=("$@")
if [[ ${#args[@]} -eq 0 ]]; then
    args=(build --release --bin mode360)
fi
# the feature and target dir go before a `--` (whose rest is for the tool, e.g. clippy's -D)
cargo_args=()
tool_args=()
for ((i = 0; i < ${#args[@]}; i++)); do
    if [[ "${args[i]}" == -- ]]; then
        tool_args=("${args[@]:i}")
        break
    fi
    cargo_args+=("${args[i]}")
done
cargo_args+=(--features cuda --target-dir "$target_dir")
echo "== cargo ${cargo_args[*]} ${tool_args[*]}"
start=$(date +%s)
cd "$repo"
cargo "${cargo_args[@]}" "${tool_args[@]}"
echo "== done in $(($(date +%s) - start)) s"
binary="$target_dir/release/mode360"
if [[ "${args[0]}" == build && -x "$binary" ]]; then
    echo "   $binary: $(du -h "$binary" | cut -f1)"
    echo "   needs: $(readelf -d "$binary" | grep -oE 'lib(cuda|cublas|cublasLt|curand|nvrtc|cudart)\.so[.0-9]*' | sort -u | tr '\n' ' ')"
    echo "   run it where an NVIDIA driver (CUDA $release or newer) provides libcuda.so.1 and the"
    echo "   libraries above are on LD_LIBRARY_PATH (PyTorch's nvidia/cu13/lib has them)."
fi
