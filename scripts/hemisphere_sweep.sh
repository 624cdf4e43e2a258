#!/usr/bin/env bash
# The narrow-lens hemisphere, the stand-in for the unseen 48-view hemisphere of issue #37: for each
# seed, `handheld demo --path hemisphere --frames 48 --fov 11 --seed S` renders the views and
# extracts their features once (kept in OUT/demo-S), then BIN reconstructs them as a user would
# (`reconstruct IMAGES --until sparse`, default options, the features reused). Prints one line per
# seed: views within 1° of the truth / registered (scripts/view_errors.py), the views named
# unconfirmed, the focal length, AUC@1 / AUC@5 (../shared/tools/eval_sfm.py against the demo's
# ground truth), the pairs (and those of the second round) and the matching and sparse times.
#
#   scripts/hemisphere_sweep.sh BIN OUT [SEED...]      (seeds 0–5 by default)
set -euo pipefail
bin=$(realpath "$1")
out=$(mkdir -p "$2" && realpath "$2")
shift 2
seeds=("$@")
[ ${#seeds[@]} -eq 0 ] && seeds=(0 1 2 3 4 5)
here=$(cd "$(dirname "$0")/.." && pwd)
eval_sfm=${HANDHELD_EVAL_SFM:-$here/../shared/tools/eval_sfm.py}
for s in "${seeds[@]}"; do
  demo=$out/demo-$s
  if [ ! -d "$demo/workspace/features" ]; then
    rm -rf "$demo"
    "$bin" --quiet demo --path hemisphere --frames 48 --fov 11 --seed "$s" --until features -o "$demo"
  fi
  ws=$out/ws-$s
  rm -rf "$ws"
  mkdir -p "$ws"
  cp -r "$demo/workspace/ingest" "$demo/workspace/features" "$ws/"
  "$bin" --quiet reconstruct "$demo/images" -o "$ws" --until sparse 2> "$out/ws-$s.err" || {
    echo "seed $s FAILED (see $out/ws-$s.err)"
    continue
  }
  python3 - "$s" "$ws" "$demo/ground_truth/sparse" "$here" "$eval_sfm" <<'PY'
import json, os, subprocess, sys, tempfile
seed, ws, gt, here, eval_sfm = sys.argv[1:6]
sys.path.insert(0, os.path.join(here, 'scripts'))
from gt_pairs import read_poses  # noqa: E402
views = subprocess.run([sys.executable, os.path.join(here, 'scripts/view_errors.py'), ws + '/sparse', gt],
                       capture_output=True, text=True).stdout.split('\n')[0].split(' registered')[0]
# eval_sfm.py reads a ground truth of one *_par.txt (name, K, R, t per line).
d = tempfile.mkdtemp()
poses = read_poses(gt)
cams = [l.split() for l in open(os.path.join(gt, 'cameras.txt')) if l.strip() and not l.startswith('#')]
w, h, f = float(cams[0][2]), float(cams[0][3]), float(cams[0][4])
with open(os.path.join(d, 'gt_par.txt'), 'w') as out:
    out.write('%d\n' % len(poses))
    for n, (r, t) in sorted(poses.items()):
        k = [f, 0, w / 2, 0, f, h / 2, 0, 0, 1]
        out.write(' '.join([n] + ['%.12g' % x for x in k + list(r.ravel()) + list(t)]) + '\n')
try:
    sc = json.loads(subprocess.run([sys.executable, eval_sfm, ws + '/sparse', d], capture_output=True,
                                   text=True).stdout or '{}')
except ValueError:
    sc = {}
s = json.load(open(ws + '/sparse/summary.json'))
m = json.load(open(ws + '/matches/summary.json'))
t = json.load(open(ws + '/timings.json'))
g = lambda k: '%.2f' % sc[k] if isinstance(sc.get(k), (int, float)) else '-'
print('seed %s: %s registered, unconfirmed %s, f %s, AUC@1 %s, AUC@5 %s, pairs %d (second round %d), '
      'matches %.1f s, sparse %.1f s' % (seed, views, s['view_consistency'].get('unconfirmed', []),
                                        [round(x['f']) for x in s['groups']], g('auc@1'), g('auc@5'),
                                        m['pairs'], m.get('second_round_pairs', 0), t.get('matches', 0),
                                        t.get('sparse', 0)))
PY
done
