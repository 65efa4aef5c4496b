#!/usr/bin/env bash
# Build esim_py's simulator (github.com/uzh-rpg/rpg_vid2e, folder esim_py) as the baseline
# module `esim_py_memory` for bench/bench_events.py --esim-py.
# Needs: a checkout of rpg_vid2e, g++, OpenCV, Eigen and Boost headers
#   (Debian: apt install libopencv-dev libeigen3-dev libboost-filesystem-dev) and pybind11
#   (.venv/bin/pip install pybind11).
# Usage: bash bench/esim_py/build.sh PATH/TO/rpg_vid2e [OUT_DIR (default bench/esim_py/build)]
set -euo pipefail
src=${1:?usage: build.sh PATH/TO/rpg_vid2e [OUT_DIR]}/esim_py
here=$(cd "$(dirname "$0")" && pwd)
out=${2:-$here/build}
py=${PYTHON:-$here/../../.venv/bin/python}
[ -f "$src/src/esim.cpp" ] || { echo "build.sh: $src/src/esim.cpp not found" >&2; exit 2; }
mkdir -p "$out"
suffix=$("$py" -c "import sysconfig; print(sysconfig.get_config_var('EXT_SUFFIX'))")
g++ -O3 -DNDEBUG -std=c++14 -shared -fPIC $("$py" -m pybind11 --includes) \
    -I"$src/include" -I/usr/include/eigen3 $(pkg-config --cflags opencv4) \
    "$src/src/esim.cpp" "$here/memory_bindings.cpp" -o "$out/esim_py_memory$suffix" \
    $(pkg-config --libs opencv4) -lboost_filesystem
echo "built $out/esim_py_memory$suffix"
