#!/usr/bin/env bash
# nvcc for `MODE360_CUDA_KERNELS=network` builds (set as NVCC by scripts/build_cuda.sh): passes
# every call to the real nvcc ($MODE360_REAL_NVCC) except those compiling candle's
# quantized-model kernels (quantized.cu, mmvq_gguf.cu, moe/*.cu, mmq_gguf/*.cu), which SSMODE
# never calls and which take most of candle's kernel build. For those it writes, instead:
#   --ptx ... FILE.cu          an empty PTX module FILE.ptx (loaded only if one of its kernels is
#                              asked for, which SSMODE never does);
#   -c -o OBJ FILE.cu          OBJ compiled from $MODE360_QUANTIZED_STUBS, weak definitions of
#                              candle-kernels' extern functions that abort with a message.
set -euo pipefail
real="${MODE360_REAL_NVCC:?MODE360_REAL_NVCC must name the real nvcc}"
args=("$@")
source_file="${args[${#args[@]}-1]}"
case "$source_file" in
*/quantized.cu | */mmvq_gguf.cu | */moe/*.cu | */mmq_gguf/*.cu) ;;
*) exec "$real" "$@" ;;
esac
out=""
ptx=0
for ((i = 0; i < ${#args[@]}; i++)); do
    case "${args[i]}" in
    -o) out="${args[i + 1]}" ;;
    --output-directory) out="${args[i + 1]}/$(basename "${source_file%.cu}").ptx" ;;
    --ptx) ptx=1 ;;
    esac
done
if [[ -z "$out" ]]; then
    echo "nvcc_network.sh: no output named in: $*" >&2
    exit 1
fi
if [[ $ptx == 1 ]]; then
    printf '.version 9.0\n.target sm_%s\n.address_size 64\n' "${CUDA_COMPUTE_CAP:-90}" >"$out"
else
    gcc -c -fPIC -o "$out" "${MODE360_QUANTIZED_STUBS:?MODE360_QUANTIZED_STUBS must name the stubs}"
fi
