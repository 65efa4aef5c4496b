#!/usr/bin/env bash
# Packs what a CUDA machine without a package index needs beyond its own PyTorch image to run
# bench/gpu_check.sh: Mitsuba and drjit (the versions in this checkout's .venv unless given),
# downloaded here as wheels for the target's Python and unpacked into one tar.gz.
#
#   bash bench/gpu_bundle.sh [PYTHON_VERSION] [OUT_TGZ]     (defaults: 3.12 gpu_bundle.tgz)
#
# Mitsuba's wheel holds 13 variants (63 MB). Only those e2sr uses are kept (cuda_ad_mono,
# llvm_ad_mono, scalar_rgb; mi.variants() still lists all 13, being compiled in, and setting
# a removed one fails with an ImportError); the spectral upsampling table (srgb.coeff, read
# by spectral variants only), the sky model's data, large plugins no e2sr scene loads
# (volumetric and particle integrators, curves, SDFs, ellipsoids, the principled BSDF), C++
# headers and type stubs go too: 45 -> 38 MB for cp311. Install on the target with
#   mkdir -p /tmp/site && tar xzf gpu_bundle.tgz -C /tmp/site && export PYTHONPATH=/tmp/site
set -euo pipefail
cd "$(dirname "$0")/.."

pyver="${1:-3.12}"
out="${2:-gpu_bundle.tgz}"
venv_version() {  # the installed version of a package in .venv, if there is one
    .venv/bin/python -c "import importlib.metadata as m; print(m.version('$1'))" 2>/dev/null
}
mitsuba_version="${MITSUBA_VERSION:-$(venv_version mitsuba)}"
drjit_version="${DRJIT_VERSION:-$(venv_version drjit)}"
if [[ -z "$mitsuba_version" || -z "$drjit_version" ]]; then
    echo "gpu_bundle: no .venv with mitsuba and drjit here; set MITSUBA_VERSION and" \
         "DRJIT_VERSION" >&2
    exit 2
fi

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
python3 -m pip install -q --no-deps --only-binary=:all: --target "$work/site" \
    --python-version "$pyver" --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    "mitsuba==$mitsuba_version" "drjit==$drjit_version"

keep="scalar_rgb llvm_ad_mono cuda_ad_mono"
mi="$work/site/mitsuba"
for module in "$mi"/*_ad_*.cpython-*.so "$mi"/scalar_*.cpython-*.so; do
    variant="$(basename "$module")"
    variant="${variant%%.cpython-*}"
    [[ " $keep " == *" $variant "* ]] || rm "$module"
done
rm -rf "$mi/data/srgb.coeff" "$mi/data/sunsky" "$mi/include" "$mi/pkgconfig" \
       "$mi/__init__.pyi" "$mi/stubs" "$work/site/bin"
for plugin in ellipsoids ellipsoidsmesh volpath volpathmis prbvolpath sunsky timed_sunsky \
              bsplinecurve linearcurve sdfgrid ptracer principled principledthin; do
    rm -f "$mi/plugins/$plugin.so"  # large plugins no e2sr scene uses
done
tar czf "$work/bundle.tgz" -C "$work/site" .
mv "$work/bundle.tgz" "$out.tmp-$$" && mv "$out.tmp-$$" "$out"  # never a half-written $out
echo "wrote $out ($(du -h "$out" | cut -f1); mitsuba $mitsuba_version, drjit $drjit_version," \
     "cp${pyver/./}, variants: $keep)"
