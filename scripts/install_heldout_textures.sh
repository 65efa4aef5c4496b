#!/usr/bin/env bash
# Install held-out test photographs and link them under data/heldout/ (re-run safely), one
# folder per package (configs/textures_heldout.yaml draws from the three equally).
# Never train, validate or select models on these: they are the images the project keeps
# for testing whether what it trains generalises (configs/textures_heldout.yaml).
#   opencv-doc                   its sample images (examples/data: the classic test photos,
#                                plus a few charts and calibration boards)
#   mate-backgrounds             its nature photographs (nature/)
#   plasma-workspace-wallpapers  the largest image of each wallpaper
# Each link is named after its package and path: stable names, so a dataset made from them
# is the same on any machine with the same packages.
set -euo pipefail
cd "$(dirname "$0")/.."
PACKAGES="opencv-doc mate-backgrounds plasma-workspace-wallpapers"
# shellcheck source=scripts/apt_packages.sh
source scripts/apt_packages.sh
ensure_packages install_heldout_textures $PACKAGES

rm -rf data/heldout.tmp && mkdir -p data/heldout.tmp/opencv data/heldout.tmp/mate \
  data/heldout.tmp/plasma
link() {  # link every image path read from stdin into data/heldout.tmp/$1
  grep -iE '\.(png|jpe?g|bmp|tiff?)$' | while read -r f; do
    ln -s "$f" "data/heldout.tmp/$1/$(echo "$f" | sed -E 's#^/usr/share/##; s#/#__#g')"
  done
}
dpkg -L opencv-doc | grep -E '/examples/data/[^/]+$' | link opencv
dpkg -L mate-backgrounds | grep -E '/backgrounds/mate/nature/' | link mate
# plasma: one image per wallpaper, its largest (sizes are in the file names)
dpkg -L plasma-workspace-wallpapers | grep -E '/contents/images/[0-9]+x[0-9]+\.(png|jpe?g)$' \
  | awk -F/ '{split($NF, s, /[x.]/); key=$(NF-3); if (s[1]*s[2] > best[key]) {best[key]=s[1]*s[2]; file[key]=$0}}
             END {for (k in file) print file[k]}' | sort | link plasma
rm -rf data/heldout && mv data/heldout.tmp data/heldout
echo "install_heldout_textures: $(ls data/heldout/opencv | wc -l) opencv-doc," \
     "$(ls data/heldout/mate | wc -l) mate-backgrounds and $(ls data/heldout/plasma | wc -l)" \
     "plasma-workspace-wallpapers image(s) in data/heldout"
