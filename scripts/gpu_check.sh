#!/usr/bin/env bash
# The GPU check of issue 29 (docs/deployment.md, "GPUs"): every material source rendered on
# cuda_ad_rgb and llvm_ad_rgb (HDR-FLIP between them under 0.01), each training kind's
# smoke run on cuda, train.brdf's paper preset timed against the paper's 10 minutes per
# 100 BRDFs, and the BTF student's frame time at 400^2. Under 10 minutes on one H200.
#
#   scripts/gpu_check.sh [OUT_DIR]           # on a machine with an NVIDIA GPU
#   MATFORGE_VARIANT=llvm_ad_rgb scripts/gpu_check.sh --cpu [OUT_DIR]
#                                            # the same path on the CPU (no comparison)
#
# Without a GPU (and without --cpu) it says so and exits 2: NOT RUN is never a pass. The
# table it prints is also written to OUT_DIR/gpu_check.md for BENCHMARKS.md.
set -euo pipefail

cd "$(dirname "$0")/.."
cpu=0
args=()
for a in "$@"; do
    case "$a" in
        --cpu) cpu=1 ;;
        --no-paper | --paper) args+=("$a") ;;
        -h | --help) sed -n '2,12p' "$0"; exit 0 ;;
        -*) echo "gpu_check: unknown option $a" >&2; exit 2 ;;
        *) out="$a" ;;
    esac
done
out="${out:-$(mktemp -d /tmp/matforge-gpu-check.XXXXXX)}"
mkdir -p "$out"

if [[ ! -x .venv/bin/matforge ]]; then
    echo "gpu_check: NOT RUN: no .venv/bin/matforge; run 'make setup' (TORCH=cuda for a GPU)" >&2
    exit 2
fi
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}"

if (( cpu )); then
    if [[ "${MATFORGE_VARIANT:-llvm_ad_rgb}" != "llvm_ad_rgb" ]]; then
        echo "gpu_check: --cpu runs llvm_ad_rgb, not MATFORGE_VARIANT=$MATFORGE_VARIANT" >&2
        exit 2
    fi
    args+=(--cpu)
else
    if ! command -v nvidia-smi > /dev/null || ! nvidia-smi -L > /dev/null 2>&1; then
        echo "gpu_check: NOT RUN: no NVIDIA GPU here (nvidia-smi finds none);" \
             "'scripts/gpu_check.sh --cpu' checks the same path on the CPU" >&2
        exit 2
    fi
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader >&2
    # The two preconditions, named: Dr.Jit must start CUDA, and torch must be a CUDA build.
    MATFORGE_VARIANT=cuda_ad_rgb .venv/bin/python -m service.workers.backend > /dev/null
    .venv/bin/python -c 'import sys, torch
if not torch.cuda.is_available():
    sys.exit(f"gpu_check: torch {torch.__version__} sees no CUDA device (make setup TORCH=cuda)")
print(f"torch {torch.__version__} on {torch.cuda.get_device_name(0)}", file=sys.stderr)'
fi

# GPU: 570 s, under the 10 minutes with room for the start-up above. --cpu: 2 shared cores
# take longer (GPU_CHECK_SECONDS overrides either).
limit="${GPU_CHECK_SECONDS:-$(( cpu ? 1800 : 570 ))}"
echo "gpu_check: writing to $out (time limit ${limit} s)" >&2
timeout --signal=TERM --kill-after=30 "$limit" \
    .venv/bin/python scripts/gpu_check.py --out "$out" "${args[@]}"
