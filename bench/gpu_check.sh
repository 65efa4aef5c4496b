#!/usr/bin/env bash
# The simulator's GPU figures in one run, for a CUDA machine whose Python already has PyTorch
# (with Triton), numba, h5py, scikit-image, OpenCV and PyYAML, e.g. a PyTorch image without
# network access. Mitsuba and drjit come from the bundle that bench/gpu_bundle.sh makes.
#
#   bash bench/gpu_check.sh OUT_DIR [BUNDLE_TGZ]          (PYTHON=... to pick the interpreter)
#
# Writes into OUT_DIR, one file per step, each step under its own time limit so that a slow
# step still leaves the others' results:
#   env.txt              GPU, driver, Python and package versions, the Mitsuba variant chosen
#   tests.log            the torch/Triton event kernels compiled on CUDA against numba, bit for
#                        bit, and the renderer tests (Mitsuba's auto variant vs the exact
#                        homography renderer)
#   bench_events.md      M pixel-updates/s: numba, numpy, torch (cpu; cuda and triton where
#                        torch sees the GPU)
#   bench_datagen.md     sequences/min, Mitsuba (auto variant: cuda_ad_mono) vs homography
#   compare_backends.md  the Mitsuba variant's events against the homography backend's
# About 2 minutes on a 2-core CPU machine (no GPU: the CUDA rows and test are left out);
# the step limits add up to 10 minutes. Exits non-zero when a step failed or ran out of time.
set -uo pipefail
if [[ $# -lt 1 ]]; then
    echo "usage: bash bench/gpu_check.sh OUT_DIR [BUNDLE_TGZ]" >&2
    exit 2
fi
repo="$(cd "$(dirname "$0")/.." && pwd)"
out="$(mkdir -p "$1" && cd "$1" && pwd)"
py="${PYTHON:-python3}"
export PYTHONUNBUFFERED=1
if [[ $# -ge 2 ]]; then
    site="$(mktemp -d)"
    trap 'rm -rf "$site"' EXIT
    tar xzf "$2" -C "$site" || { echo "gpu_check: cannot unpack $2" >&2; exit 2; }
    export PYTHONPATH="$site:$repo"
else
    export PYTHONPATH="$repo"
fi
cd "$repo"

failed=0
step() {  # step NAME LIMIT_S FILE COMMAND...: run, keep its output, say how it ended
    local name="$1" limit="$2" file="$3"
    shift 3
    local start=$SECONDS
    timeout "$limit" "$@" >"$out/$file" 2>&1
    local rc=$?
    echo "$name: exit $rc after $((SECONDS - start)) s -> $file"
    [[ $rc -eq 0 ]] || failed=1
}

{
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
    echo "cpus: $(nproc)"
    "$py" - <<'EOF'
import importlib.metadata as md
import platform

print("python", platform.python_version())
for name in ("torch", "triton", "numba", "numpy", "mitsuba", "drjit", "h5py"):
    try:
        print(name, md.version(name))
    except md.PackageNotFoundError:
        print(name, "missing")
import torch

print("torch sees CUDA:", torch.cuda.is_available(),
      torch.cuda.get_device_name(0) if torch.cuda.is_available() else "")
from esim_lite.render.mitsuba import resolve_variant

print("mitsuba auto variant:", resolve_variant("auto"))
EOF
} >"$out/env.txt" 2>&1
echo "env: -> env.txt"

step tests 240 tests.log "$py" -m pytest -q -rs -p no:cacheprovider \
    tests/esim_lite/test_event_triton.py tests/esim_lite/test_event_torch.py \
    tests/esim_lite/test_render.py
step bench_events 120 bench_events.md "$py" bench/bench_events.py --repeats 3
step bench_datagen 150 bench_datagen.md "$py" bench/bench_datagen.py --ratio --n-seq 4 \
    --repeats 2 --workers 1
step compare_backends 120 compare_backends.md "$py" bench/compare_backends.py --n-seq 4
exit $failed
