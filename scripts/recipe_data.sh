#!/usr/bin/env bash
# The recipe's training set in one command (docs/models.md, "The recipe"):
#   bash scripts/recipe_data.sh OUT [N_SEQ] [extra `datagen generate` arguments ...]
# writes N_SEQ sequences (default 1000) as five datasets under OUT and links them into
# OUT/mix, the folder `train --data` reads. The parts, each with its own seed and at least
# one sequence, follow the mix the shipped x2 model (K) was fine-tuned on, rebalanced
# towards moving objects:
#   OUT/plane         40%  the textured plane, the randomised calibrated sensor
#                          (datagen_realistic + datagen_realistic_plane)
#   OUT/clean         20%  the textured plane, the ideal sensor of the paper's recipe
#                          (datagen_train)
#   OUT/dynamic       20%  0-8 independently moving objects with occlusion, 20% of them
#                          filmed by a static camera; the randomised sensor
#                          (datagen_realistic + datagen_realistic_dynamic)
#   OUT/static        10%  static cameras over 1-8 moving objects (+ datagen_static_camera)
#   OUT/static_small  10%  static cameras over 2-10 small objects (+ datagen_static_small)
# The randomised sensor draws thresholds, mismatch, noise, bandwidth, flicker and latency
# per sequence (configs/datagen_realistic.yaml). Environment: SCALE (2; 4 for the x4
# model), SEED (1; part k uses SEED*100+k), WORKERS (2), TEXTURES (a textures config,
# default configs/textures_train.yaml after `bash scripts/install_textures.sh`; `builtin`
# for the built-in textures alone). Re-run safely: `datagen generate` resumes each part.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 1 ] || { echo "usage: recipe_data.sh OUT [N_SEQ] [datagen generate args ...]" >&2; exit 2; }
out=$1; shift
n=1000
if [ $# -ge 1 ] && [[ $1 =~ ^[0-9]+$ ]]; then n=$1; shift; fi
[ "$n" -ge 5 ] || { echo "recipe_data: N_SEQ must be at least 5 (one per part), got $n" >&2; exit 2; }
scale=${SCALE:-2}; seed=${SEED:-1}; workers=${WORKERS:-2}
textures=${TEXTURES:-configs/textures_train.yaml}
if [ "$textures" = builtin ]; then tex=(--textures builtin); else tex=(--config "$textures"); fi
gen=".venv/bin/datagen"
[ -x "$gen" ] || gen=datagen

# name, share in percent, configs
parts=(
  "plane 40 configs/datagen_realistic.yaml configs/datagen_realistic_plane.yaml"
  "clean 20 configs/datagen_train.yaml"
  "dynamic 20 configs/datagen_realistic.yaml configs/datagen_realistic_dynamic.yaml"
  "static 10 configs/datagen_realistic.yaml configs/datagen_realistic_dynamic.yaml configs/datagen_static_camera.yaml"
  "static_small 10 configs/datagen_realistic.yaml configs/datagen_realistic_dynamic.yaml configs/datagen_static_small.yaml"
)
left=$n; k=0; folders=()
for part in "${parts[@]}"; do
  read -r name share configs <<<"$part"
  k=$((k + 1))
  if [ "$k" -eq "${#parts[@]}" ]; then count=$left; else
    count=$(( n * share / 100 )); [ "$count" -ge 1 ] || count=1
    left_after=$(( left - count )); remaining=$(( ${#parts[@]} - k ))
    [ "$left_after" -ge "$remaining" ] || count=$(( left - remaining ))
  fi
  left=$(( left - count ))
  args=()
  for c in $configs; do args+=(--config "$c"); done
  echo "recipe_data: $name: $count sequence(s), seed $((seed * 100 + k))"
  "$gen" generate "${args[@]}" "${tex[@]}" --n-seq "$count" --seed $((seed * 100 + k)) \
    --scale "$scale" --workers "$workers" --out "$out/$name" "$@"
  folders+=("$out/$name")
done
bash scripts/link_shards.sh "$out/mix" "${folders[@]}"
