#!/usr/bin/env bash
# Gather the shards of several datasets into one training folder of links:
#   bash scripts/link_shards.sh OUT DATASET [DATASET ...]
# Each link is named shard_<dataset folder>_<shard>.h5, so names stay unique and stable
# (the validation split hashes shard and sequence names). Re-run safely: OUT's shard links
# are replaced, anything else in it (train's input cache) is kept.
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: link_shards.sh OUT DATASET [DATASET ...]" >&2; exit 2; }
out=$1; shift
for d in "$@"; do
  ls "$d"/shard_*.h5 >/dev/null 2>&1 || { echo "link_shards: $d: no shard_*.h5 files" >&2; exit 2; }
done
mkdir -p "$out"
find "$out" -maxdepth 1 -name 'shard_*.h5' -type l -delete
for d in "$@"; do
  for f in "$d"/shard_*.h5; do
    ln -s "$(realpath "$f")" "$out/shard_$(basename "$d")_$(basename "$f" .h5 | sed 's/^shard_//').h5"
  done
done
echo "link_shards: $(find "$out" -maxdepth 1 -name 'shard_*.h5' | wc -l) shard(s) in $out"
