#!/usr/bin/env bash
# Makes the low-texture stress set of issue #34 from templeSparseRing and dinoSparseRing (32 images):
# each image blurred (σ 1.5), its contrast cut to 35 % and noise added with a seed of its own (one
# seed for all would give every image the same noise pattern, and every pair would "verify" as a
# homography on it). About 35 of the 496 pairs verify. Needs ffmpeg.
#
#   scripts/lowtex_set.sh /tmp/lowtex
#   handheld --json bench matching --images /tmp/lowtex --exhaustive --threads 2
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
data=${HANDHELD_DATASETS:-$here/../shared/datasets}
out=$1
mkdir -p "$out"
i=0
for f in "$data"/templeSparseRing/images/*.png "$data"/dinoSparseRing/images/*.png; do
  i=$((i + 1))
  ffmpeg -y -loglevel error -i "$f" \
    -vf "gblur=sigma=1.5,eq=contrast=0.35,noise=alls=8:all_seed=$((i * 7919))" \
    "$out/$(basename "$f")"
done
echo "$i images in $out"
