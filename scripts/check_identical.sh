#!/usr/bin/env bash
# Behaviour check for refactors: runs one `handheld` binary on the demo (photos, and video with
# augmentation), fountain-P11, templeSparseRing and kitti-seq1 encoded as a video (augmented), and
# writes one line per output file: its SHA-256 (videos: the MD5 of every decoded frame, so the
# container's metadata does not count). Run it for the binary before and after a change, then diff.
#
#   scripts/check_identical.sh BIN OUT_DIR     # writes OUT_DIR/hashes.txt
#   diff before/hashes.txt after/hashes.txt
#   HASH_ONLY=1 scripts/check_identical.sh BIN OUT_DIR   # hashes an earlier run's outputs again
#
# Manifests, timings, summaries, logs and the report (which carry times and the warnings' wording)
# are left out; models, depth maps, meshes, renders and augmented frames are in.
set -euo pipefail
bin=$(realpath "$1")
out=$(realpath -m "$2")
data=$(realpath "$(dirname "$0")/../../shared/datasets")
mkdir -p "$out"
cd "$out"
run() { echo "== $*" >&2; "$bin" --quiet "$@" > /dev/null; }

if [ -z "${HASH_ONLY:-}" ]; then
  run demo -o demo
  run demo -o demo-video --video --frames 30 --augment
  run reconstruct "$data/fountain-P11/images" -o fountain
  run reconstruct "$data/templeSparseRing/images" -o temple
  if [ ! -f kitti.mp4 ]; then
    ffmpeg -nostdin -loglevel error -y -framerate 10 -i "$data/kitti-seq1/images/%06d.png" \
      -c:v libx264 -preset medium -crf 18 -pix_fmt yuv420p -threads 1 kitti.mp4
  fi
  run augment kitti.mp4 -o kitti --object box || echo "kitti augment failed (exit $?)" >&2
fi

: > hashes.txt
find demo demo-video fountain temple kitti -type f \
  ! -name manifest.json ! -name timings.json ! -name summary.json ! -name '*.log' \
  ! -name report.html ! -path '*/report/*' | LC_ALL=C sort | while read -r f; do
  case "$f" in
    *.mp4) echo "$(ffmpeg -nostdin -loglevel error -i "$f" -f framemd5 - | grep -v '^#' | sha256sum | cut -c1-64)  $f (frames)" ;;
    *) sha256sum "$f" ;;
  esac
done >> hashes.txt
wc -l hashes.txt >&2
