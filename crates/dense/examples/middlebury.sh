#!/usr/bin/env bash
# Scores and times SGM, DP and OpenCV StereoSGBM on the Middlebury teddy and cones pairs
# (64 disparities), interleaved so that all three see the same machine load.
# Run from the repository root:  crates/dense/examples/middlebury.sh [OUT_DIR] [--set K=V]...
# Needs: python3 with numpy, pillow and opencv-python-headless.
set -euo pipefail
OUT=${1:-/tmp/middlebury}
shift || true
DATA=../shared/datasets
EVAL=../shared/tools/eval_stereo.py
mkdir -p "$OUT"
cargo build --release -q -p handheld-dense --example stereo_pair
BIN=target/release/examples/stereo_pair
for s in teddy cones; do
  D=$DATA/stereo-$s
  echo "== $s"
  python3 crates/dense/examples/opencv_sgbm.py "$D/im2.png" "$D/im6.png" "$OUT/opencv_$s.pfm"
  python3 "$EVAL" "$OUT/opencv_$s.pfm" "$D/disp2.pgm" 4
  for m in sgm dp; do
    "$BIN" "$D/im2.png" "$D/im6.png" "$OUT/${m}_$s.pfm" --method "$m" "$@"
    python3 "$EVAL" "$OUT/${m}_$s.pfm" "$D/disp2.pgm" 4
  done
done
