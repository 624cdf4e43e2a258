#!/usr/bin/env python3
"""How many of each verified pair's inliers the true epipolar geometry explains. For a workspace made
from synthetic images (`handheld demo`, whose ground truth is a COLMAP text model with a RADIAL
camera), every pair of `matches/database.db` is scored: the Sampson distance (pixels) of its inlier
matches under the true relative pose, after the true distortion is undone. Pairs where more than a
share of the inliers lie beyond a bound are listed, worst first.

    scripts/gt_pairs.py DEMO/workspace DEMO/ground_truth/sparse [--bound-px 3] [--share 0.2]
"""
import argparse
import sqlite3

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from gt_dense_model import quat_to_rot  # noqa: E402

PAIR_ID_BASE = 2147483647


def read_poses(sparse):
    """name -> (R, t) of a COLMAP images.txt (world -> camera)."""
    lines = [l.rstrip("\n") for l in open(f"{sparse}/images.txt") if not l.startswith("#")]
    poses, i = {}, 0
    while i < len(lines):
        p = lines[i].split()
        if len(p) >= 10 and "." in p[9]:
            poses[p[9]] = (quat_to_rot([float(v) for v in p[1:5]]), np.array([float(v) for v in p[5:8]]))
            i += 2
        else:
            i += 1
    return poses


def read_camera(sparse):
    """(f, cx, cy, [k1, k2]) of the first camera of a COLMAP cameras.txt (SIMPLE_RADIAL or RADIAL)."""
    p = next(l for l in open(f"{sparse}/cameras.txt") if not l.startswith("#")).split()
    return float(p[4]), float(p[5]), float(p[6]), [float(v) for v in p[7:]]


def undistort(px, cam):
    f, cx, cy, k = cam
    x, y = (px[:, 0] - cx) / f, (px[:, 1] - cy) / f
    xu, yu = x.copy(), y.copy()
    for _ in range(30):
        r2 = xu * xu + yu * yu
        d = 1 + (k[0] if k else 0) * r2 + (k[1] if len(k) > 1 else 0) * r2 * r2
        xu, yu = x / d, y / d
    return np.c_[xu, yu, np.ones(len(x))]


def skew(t):
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("workspace")
    ap.add_argument("gt_sparse")
    ap.add_argument("--bound-px", type=float, default=3.0)
    ap.add_argument("--share", type=float, default=0.2)
    a = ap.parse_args()
    poses, cam = read_poses(a.gt_sparse), read_camera(a.gt_sparse)
    db = sqlite3.connect(f"{a.workspace}/matches/database.db")
    names = dict(db.execute("select image_id, name from images"))
    cache = {}

    def keypoints(i):
        if i not in cache:
            r, c, d = db.execute("select rows, cols, data from keypoints where image_id=?", (i,)).fetchone()
            cache[i] = np.frombuffer(d, np.float32).reshape(r, c)[:, :2].astype(float)
        return cache[i]

    rows = []
    for pid, n, cols, data in db.execute("select pair_id, rows, cols, data from two_view_geometries"):
        if not n:
            continue
        j = pid % PAIR_ID_BASE
        i = (pid - j) // PAIR_ID_BASE
        m = np.frombuffer(data, np.uint32).reshape(n, cols)
        xa, xb = undistort(keypoints(i)[m[:, 0]], cam), undistort(keypoints(j)[m[:, 1]], cam)
        (ra, ta), (rb, tb) = poses[names[i]], poses[names[j]]
        r = rb @ ra.T
        e = skew(tb - r @ ta) @ r
        ea, etb = xa @ e.T, xb @ e
        d = np.abs(np.sum(xb * ea, 1)) / np.sqrt(ea[:, 0] ** 2 + ea[:, 1] ** 2 + etb[:, 0] ** 2 + etb[:, 1] ** 2) * cam[0]
        rows.append((names[i], names[j], n, float(np.median(d)), float(np.mean(d > a.bound_px))))
    bad = sorted((r for r in rows if r[4] > a.share), key=lambda r: -r[4])
    print(f"{len(rows)} verified pairs; {len(bad)} with more than {100 * a.share:.0f} % of their inliers "
          f"beyond {a.bound_px} px of the true epipolar geometry")
    for r in bad:
        print(f"{r[0]} {r[1]}: {r[2]} inliers, median {r[3]:.2f} px, {100 * r[4]:.0f} % beyond")


if __name__ == "__main__":
    main()
