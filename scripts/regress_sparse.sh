#!/usr/bin/env bash
# Runs one handheld binary up to the sparse model on every image data set in ../shared/datasets
# (uncalibrated, defaults) and prints one line per set: registered views, focal length, the
# scores of ../shared/tools/eval_sfm.py where the set has ground truth, and the sparse stage's
# time. Two binaries on the same machine, one after the other, compare a change.
#
#   scripts/regress_sparse.sh BIN OUT [SET...]
#
# OUT gets one workspace per set and results.tsv. Needs python3 + numpy for the scores.
set -euo pipefail
bin=$(realpath "$1")
out=$2
shift 2
here=$(cd "$(dirname "$0")/.." && pwd)
data=${HANDHELD_DATASETS:-$here/../shared/datasets}
eval_sfm=${HANDHELD_EVAL_SFM:-$data/../tools/eval_sfm.py}
sets=("$@")
if [ ${#sets[@]} -eq 0 ]; then
  sets=(fountain-P11 herzjesu-P8 templeSparseRing dinoSparseRing kitti-seq1 iclnuim-5 monstree-phone bundler-ET bundler-kermit sceaux-castle)
fi
mkdir -p "$out"
printf 'set\tregistered\tfocal_px\tauc@1\tauc@5\trot_med_deg\tfocal_err_pct\tsparse_s\n' > "$out/results.tsv"
for s in "${sets[@]}"; do
  ws=$out/$s
  rm -rf "$ws"
  if ! "$bin" --quiet reconstruct "$data/$s/images" -o "$ws" --until sparse 2> "$out/$s.err"; then
    printf '%s\tFAILED\t\t\t\t\t\t\n' "$s" >> "$out/results.tsv"
    continue
  fi
  scores='{}'
  if [ -d "$data/$s/gt" ] && [ -f "$eval_sfm" ]; then
    scores=$(python3 "$eval_sfm" "$ws/sparse" "$data/$s" 2>/dev/null || echo '{}')
  fi
  python3 - "$s" "$ws" "$scores" >> "$out/results.tsv" <<'EOF'
import json, sys
name, ws, scores = sys.argv[1], sys.argv[2], json.loads(sys.argv[3] or '{}')
summ = json.load(open(f'{ws}/sparse/summary.json'))
try:
    man = json.load(open(f'{ws}/sparse/manifest.json'))
    secs = man.get('seconds', '')
except Exception:
    secs = ''
focal = ','.join(f"{g['f']:.1f}" for g in summ.get('groups', []))
def g(k, fmt='{:.2f}'):
    v = scores.get(k)
    return fmt.format(v) if isinstance(v, (int, float)) else ''
rot = scores.get('rot_err_deg_median')
print('\t'.join([name, f"{summ['registered']}/{summ['total_images']}", focal, g('auc@1'), g('auc@5'),
                 f'{rot:.3f}' if isinstance(rot, (int, float)) else '', g('focal_err_pct_median', '{:.3f}'),
                 f'{secs:.1f}' if isinstance(secs, (int, float)) else str(secs)]))
EOF
done
column -t -s $'\t' "$out/results.tsv"
