#!/usr/bin/env bash
# Times the whole sparse pipeline (images → metric model) of Handheld and of COLMAP 3.8
# (feature_extractor + exhaustive_matcher + mapper, SIMPLE_RADIAL, one shared camera) on the same
# data set in the same run, scores both with ../shared/tools/eval_sfm.py, and prints one JSON object.
# Usage: scripts/bench_sfm_vs_colmap.sh [DATASET_DIR] [WORK_DIR]
set -euo pipefail
DATA=${1:-../shared/datasets/fountain-P11}
WORK=${2:-$(mktemp -d)}
HH=${HANDHELD:-target/release/handheld}
EVAL=${EVAL:-../shared/tools/eval_sfm.py}
command -v colmap >/dev/null || { echo '{"error":"colmap not installed (apt install colmap)"}'; exit 1; }
[ -x "$HH" ] || cargo build --release -p handheld >&2
rm -rf "$WORK/hh" "$WORK/colmap"; mkdir -p "$WORK/colmap/sparse"
t0=$(date +%s.%N)
"$HH" --quiet reconstruct "$DATA/images" -o "$WORK/hh" --until sparse
t1=$(date +%s.%N)
export QT_QPA_PLATFORM=offscreen
colmap feature_extractor --database_path "$WORK/colmap/db.db" --image_path "$DATA/images" \
  --ImageReader.single_camera 1 --ImageReader.camera_model SIMPLE_RADIAL --SiftExtraction.use_gpu 0 >/dev/null 2>&1
t2=$(date +%s.%N)
colmap exhaustive_matcher --database_path "$WORK/colmap/db.db" --SiftMatching.use_gpu 0 >/dev/null 2>&1
t3=$(date +%s.%N)
colmap mapper --database_path "$WORK/colmap/db.db" --image_path "$DATA/images" --output_path "$WORK/colmap/sparse" >/dev/null 2>&1
t4=$(date +%s.%N)
mkdir -p "$WORK/colmap/txt"
colmap model_converter --input_path "$WORK/colmap/sparse/0" --output_path "$WORK/colmap/txt" --output_type TXT >/dev/null 2>&1
hh_eval=$(python3 "$EVAL" "$WORK/hh/sparse" "$DATA" | tail -1)
cm_eval=$(python3 "$EVAL" "$WORK/colmap/txt" "$DATA" | tail -1)
python3 - "$t0" "$t1" "$t2" "$t3" "$t4" "$hh_eval" "$cm_eval" "$WORK/hh/timings.json" <<'PY'
import json, sys
t = list(map(float, sys.argv[1:6]))
hh = t[1] - t[0]; cm = t[4] - t[1]
print(json.dumps({
  "handheld_s": round(hh, 2),
  "handheld_stages_s": json.load(open(sys.argv[8])) if sys.argv[8] else None,
  "colmap_s": round(cm, 2),
  "colmap_stages_s": {"feature_extractor": round(t[2]-t[1], 2), "exhaustive_matcher": round(t[3]-t[2], 2), "mapper": round(t[4]-t[3], 2)},
  "speedup": round(cm / hh, 2),
  "handheld_eval": json.loads(sys.argv[6]),
  "colmap_eval": json.loads(sys.argv[7]),
}))
PY
