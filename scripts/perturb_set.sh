#!/usr/bin/env bash
# Makes three perturbed copies of an image data set, for telling a change's effect from noise:
# JPEG at high quality, 3 px cut from each edge, and scaled to 0.9. Each copy gets the set's gt/
# linked, so ../shared/tools/eval_sfm.py scores it (the poses do not change; the focal length does
# under scaling). Needs ffmpeg.
#
#   scripts/perturb_set.sh ../shared/datasets/templeSparseRing /tmp/tvar
#   HANDHELD_DATASETS=/tmp/tvar HANDHELD_EVAL_SFM=../shared/tools/eval_sfm.py \
#       scripts/regress_sparse.sh BIN OUT jpg crop scale
set -euo pipefail
src=$(realpath "$1")
out=$2
for v in jpg crop scale; do
  mkdir -p "$out/$v/images"
  ln -sfn "$src/gt" "$out/$v/gt"
done
for f in "$src"/images/*; do
  b=$(basename "${f%.*}")
  ffmpeg -y -loglevel error -i "$f" -q:v 2 "$out/jpg/images/$b.jpg"
  ffmpeg -y -loglevel error -i "$f" -vf crop=iw-6:ih-6:3:3 "$out/crop/images/$b.png"
  ffmpeg -y -loglevel error -i "$f" -vf 'scale=iw*0.9:-1' "$out/scale/images/$b.png"
done
