#!/usr/bin/env python3
"""How well a data set's ground-truth cameras explain our matches. Every track of a sparse model
(COLMAP text) is re-triangulated (linear DLT) with the ground-truth cameras, and its observations'
reprojection errors are summarised, over all tracks of three or more views and per pair of views.
Set beside the model's own reprojection error, it tells whether the ground truth is accurate enough
to rank two models that differ by hundredths of a degree.

    scripts/gt_reprojection.py WORKSPACE/sparse ../shared/datasets/templeSparseRing/gt/templeSR_par.txt
    scripts/gt_reprojection.py WORKSPACE/sparse ../shared/datasets/iclnuim-5

The second form reads `gt/pose.txt` + `gt/intrinsics.txt` through ../shared/tools/eval_sfm.py
(set HANDHELD_EVAL_SFM to use another copy).
"""
import os
import sys
from collections import defaultdict

import numpy as np


def middlebury(par):
    gt = {}
    for line in open(par).read().split("\n")[1:]:
        p = line.split()
        if len(p) < 22:
            continue
        K = np.array(p[1:10], float).reshape(3, 3)
        R = np.array(p[10:19], float).reshape(3, 3)
        t = np.array(p[19:22], float)
        gt[os.path.splitext(p[0])[0]] = K @ np.c_[R, t]
    return gt


def pose_and_intrinsics(ds):
    here = os.path.dirname(os.path.abspath(__file__))
    tool = os.environ.get("HANDHELD_EVAL_SFM", os.path.join(here, "..", "..", "shared", "tools", "eval_sfm.py"))
    sys.path.insert(0, os.path.dirname(tool))
    import eval_sfm  # noqa: E402

    fx, fy, cx, cy = [float(v) for line in open(os.path.join(ds, "gt", "intrinsics.txt"))
                      if not line.startswith("#") for v in line.split()][:4]
    # eval_sfm flips a negative fy's y axis into the camera frame; the image keeps its own.
    K = np.array([[fx, 0, cx], [0, abs(fy), cy], [0, 0, 1]])
    return {eval_sfm.key(n): K @ np.c_[v["R"], -v["R"] @ v["C"]] for n, v in eval_sfm.read_gt(ds).items()}


def triangulate(obs):
    rows = []
    for P, x in obs:
        rows += [x[0] * P[2] - P[0], x[1] * P[2] - P[1]]
    X = np.linalg.svd(np.array(rows))[2][-1]
    return [np.linalg.norm((P @ X)[:2] / (P @ X)[2] - x) for P, x in obs]


def main():
    model, source = sys.argv[1], sys.argv[2]
    gt = pose_and_intrinsics(source) if os.path.isdir(source) else middlebury(source)
    lines = [l for l in open(os.path.join(model, "images.txt")) if not l.startswith("#")]
    images = {}
    for i in range(0, len(lines) - 1, 2):
        h, xy = lines[i].split(), lines[i + 1].split()
        images[int(h[0])] = (os.path.splitext(h[9])[0], np.array(xy, float).reshape(-1, 3))
    errors, own, pairs = [], [], defaultdict(list)
    for line in open(os.path.join(model, "points3D.txt")):
        if line.startswith("#"):
            continue
        fields = line.split()
        own.append(float(fields[7]))
        track = np.array(fields[8:], float).reshape(-1, 2).astype(int)
        views = [(images[i][0], images[i][1][k, :2]) for i, k in track if images[i][0] in gt]
        for a in range(len(views)):
            for b in range(a + 1, len(views)):
                (na, xa), (nb, xb) = views[a], views[b]
                pairs[tuple(sorted((na, nb)))].append(max(triangulate([(gt[na], xa), (gt[nb], xb)])))
        if len(views) >= 3:
            errors += triangulate([(gt[n], x) for n, x in views])
    print(f"the model's own reprojection error: mean {np.mean(own):.3f} px over {len(own)} points")
    if errors:
        e = np.array(errors)
        print(f"{len(e)} observations of tracks with 3+ views; ground-truth cameras reproject them with "
              f"median {np.median(e):.3f} px, RMS {np.sqrt((e ** 2).mean()):.3f} px")
    print("per pair of views (2-view triangulation with the ground-truth cameras, the larger of the two errors):")
    for (a, b), e in sorted(pairs.items()):
        print(f"  {a} {b}: {len(e)} points, median {np.median(e):.3f} px")


if __name__ == "__main__":
    main()
