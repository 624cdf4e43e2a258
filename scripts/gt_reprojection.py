#!/usr/bin/env python3
"""How well a data set's ground-truth cameras explain our matches: every track of three or more
views in a sparse model (COLMAP text) is re-triangulated (linear DLT) with the ground-truth cameras
of a Middlebury `*_par.txt` (name K R t), and its observations' reprojection errors are summarised.
Set beside the model's own reprojection error, it tells whether the ground truth is accurate enough
to rank two models that differ by hundredths of a degree.

    scripts/gt_reprojection.py WORKSPACE/sparse ../shared/datasets/templeSparseRing/gt/templeSR_par.txt
"""
import os
import sys

import numpy as np


def main():
    model, par = sys.argv[1], sys.argv[2]
    gt = {}
    for line in open(par).read().split("\n")[1:]:
        p = line.split()
        if len(p) < 22:
            continue
        K = np.array(p[1:10], float).reshape(3, 3)
        R = np.array(p[10:19], float).reshape(3, 3)
        t = np.array(p[19:22], float)
        gt[os.path.splitext(p[0])[0]] = K @ np.c_[R, t]
    lines = [l for l in open(os.path.join(model, "images.txt")) if not l.startswith("#")]
    images = {}
    for i in range(0, len(lines) - 1, 2):
        h, xy = lines[i].split(), lines[i + 1].split()
        images[int(h[0])] = (os.path.splitext(h[9])[0], np.array(xy, float).reshape(-1, 3))
    errors = []
    for line in open(os.path.join(model, "points3D.txt")):
        if line.startswith("#"):
            continue
        track = np.array(line.split()[8:], float).reshape(-1, 2).astype(int)
        if len(track) < 3:
            continue
        rows, obs = [], []
        for image_id, k in track:
            name, xy = images[image_id]
            P, x = gt[name], xy[k, :2]
            rows += [x[0] * P[2] - P[0], x[1] * P[2] - P[1]]
            obs.append((P, x))
        X = np.linalg.svd(np.array(rows))[2][-1]
        for P, x in obs:
            q = P @ X
            errors.append(np.linalg.norm(q[:2] / q[2] - x))
    e = np.array(errors)
    print(f"{len(e)} observations of tracks with 3+ views; ground-truth cameras reproject them with "
          f"median {np.median(e):.3f} px, RMS {np.sqrt((e ** 2).mean()):.3f} px")


if __name__ == "__main__":
    main()
