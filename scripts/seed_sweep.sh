#!/usr/bin/env bash
# Runs one handheld binary up to the sparse model on one data set with the seeds 0..N-1 (`--seed`,
# every random choice of the sparse stage), scores each model with ../shared/tools/eval_sfm.py, and
# prints one line per seed and then the mean, median and worst of AUC@1 and AUC@5. A set of five
# views can move by tenths of an AUC point from one seed to the next; two binaries are compared by
# these distributions, not by one run each.
#
#   scripts/seed_sweep.sh BIN SET N [OUT]
set -euo pipefail
bin=$(realpath "$1")
set_name=$2
n=$3
here=$(cd "$(dirname "$0")/.." && pwd)
data=${HANDHELD_DATASETS:-$here/../shared/datasets}
eval_sfm=${HANDHELD_EVAL_SFM:-$data/../tools/eval_sfm.py}
out=${4:-$(mktemp -d)}
mkdir -p "$out"
: > "$out/seeds.jsonl"
for ((s = 0; s < n; s++)); do
  ws=$out/seed$s
  rm -rf "$ws"
  if "$bin" --quiet reconstruct "$data/$set_name/images" -o "$ws" --until sparse --seed "$s" 2> "$out/seed$s.err"; then
    python3 "$eval_sfm" "$ws/sparse" "$data/$set_name" | python3 -c "import json,sys; d=json.load(sys.stdin); d['seed']=$s; print(json.dumps(d))" >> "$out/seeds.jsonl"
  else
    echo "{\"seed\": $s, \"failed\": true}" >> "$out/seeds.jsonl"
  fi
  rm -rf "$ws"
done
python3 - "$out/seeds.jsonl" <<'PY'
import json, statistics, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
for r in runs:
    if r.get('failed'):
        print(f"seed {r['seed']:3d}  FAILED")
    else:
        print(f"seed {r['seed']:3d}  {r['registered']}/{r['images']}  AUC@1 {r['auc@1']:6.2f}  AUC@5 {r['auc@5']:6.2f}  rot {r['rot_err_deg_median']:.4f} deg")
ok = [r for r in runs if not r.get('failed')]
for k in ('auc@1', 'auc@5'):
    v = [r[k] for r in ok]
    if v:
        print(f"{k}: mean {statistics.mean(v):.2f}, median {statistics.median(v):.2f}, worst {min(v):.2f} over {len(v)} seeds ({len(runs) - len(ok)} failed)")
PY
