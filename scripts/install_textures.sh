#!/usr/bin/env bash
# Install the training texture sources and link them under data/textures/ (re-run safely).
#   data/textures/ufoai/       Debian's ufoai-textures: 2,720 material textures in one .pk3
#                              (its normal/specular/gloss maps are excluded by datagen)
#   data/textures/wallpapers/  the raster images of Debian's gnome-backgrounds and
#                              ukui-wallpapers (SVGs are skipped: datagen reads raster images)
#   data/textures/games/       surface textures of two games' data packages: supertuxkart-data
#                              (data/textures, data/tracks: rock, bark, foliage, walls, roads)
#                              and flightgear-data-base (Textures/: terrain, trees, water, sky,
#                              runways); not their UI art, kart skins or model atlases
# Only these packages (plus scikit-image's photos and the procedural patterns) are training
# sources. Every other image package is kept for held-out testing: this script links the
# files these two packages own (dpkg -L), never a whole shared folder such as
# /usr/share/backgrounds, where other packages install their images too.
set -euo pipefail
cd "$(dirname "$0")/.."
PACKAGES="ufoai-textures gnome-backgrounds ukui-wallpapers supertuxkart-data flightgear-data-base"
# shellcheck source=scripts/apt_packages.sh
source scripts/apt_packages.sh
ensure_packages install_textures $PACKAGES

rm -rf data/textures.tmp && mkdir -p data/textures.tmp/ufoai data/textures.tmp/wallpapers \
  data/textures.tmp/games
dpkg -L ufoai-textures | grep -E '\.pk3$' | while read -r f; do
  ln -s "$f" data/textures.tmp/ufoai/
done
for p in gnome-backgrounds ukui-wallpapers; do
  dpkg -L "$p" | grep -iE '\.(png|jpe?g|webp|bmp|tiff?)$' | while read -r f; do
    ln -s "$f" "data/textures.tmp/wallpapers/${p}__$(basename "$f")"
  done
done
# one flat folder of links, each named after its package and path (unique, stable names:
# the train/test split hashes the name)
{ dpkg -L supertuxkart-data | grep -E '/supertuxkart/data/(textures|tracks)/'
  dpkg -L flightgear-data-base \
    | grep -E '/flightgear/Textures/(Terrain|Terrain\.winter|Trees|Water|Sky|Runway)/'
} | grep -iE '\.(png|jpe?g)$' | while read -r f; do
  name=$(echo "$f" | sed -E 's#^/usr/share/games/##; s#/#__#g')
  ln -s "$f" "data/textures.tmp/games/$name"
done
rm -rf data/textures && mv data/textures.tmp data/textures
echo "install_textures: $(ls data/textures/ufoai | wc -l) archive(s) in data/textures/ufoai," \
     "$(ls data/textures/wallpapers | wc -l) image(s) in data/textures/wallpapers," \
     "$(ls data/textures/games | wc -l) image(s) in data/textures/games"
