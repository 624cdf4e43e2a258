#!/usr/bin/env python3
"""Writes a COLMAP text model with a data set's ground-truth cameras (Strecha `.camera` files) and
sparse points taken from one of our models, moved into the GT frame by the similarity that aligns
the camera centres. `handheld dense --model OUT --images DATASET/images` then densifies with the GT
cameras (issue #6, Done-when 3), the sparse points only fixing the disparity ranges.

usage: gt_dense_model.py DATASET OUR_SPARSE_MODEL_DIR OUT_DIR
"""
import os
import sys

import numpy as np


def read_strecha(path):
    v = [float(x) for x in open(path).read().split()]
    k = np.array(v[0:9]).reshape(3, 3)
    r_world_from_cam = np.array(v[12:21]).reshape(3, 3)
    c = np.array(v[21:24])
    w, h = int(v[24]), int(v[25])
    return k, r_world_from_cam, c, w, h


def rot_to_quat(r):
    w = np.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return w, x, y, z


def quat_to_rot(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def read_our_model(d):
    centres, points = {}, []
    lines = [l for l in open(os.path.join(d, "images.txt")) if not l.startswith("#")]
    for i in range(0, len(lines), 2):
        t = lines[i].split()
        if len(t) < 10:
            continue
        q = [float(x) for x in t[1:5]]
        tr = np.array([float(x) for x in t[5:8]])
        r = quat_to_rot(q)
        centres[t[9]] = -r.T @ tr
    for l in open(os.path.join(d, "points3D.txt")):
        if l.startswith("#") or not l.strip():
            continue
        t = l.split()
        points.append([float(x) for x in t[1:4]])
    return centres, np.array(points)


def umeyama(src, dst):
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, s, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.eye(3)
    if np.linalg.det(u @ vt) < 0:
        d[2, 2] = -1
    r = u @ d @ vt
    scale = np.trace(np.diag(s) @ d) / (a ** 2).sum(1).mean()
    return scale, r, md - scale * r @ ms


def main():
    dataset, ours, out = sys.argv[1:4]
    gt = {}
    for f in sorted(os.listdir(os.path.join(dataset, "gt"))):
        if f.endswith(".camera"):
            gt[f[: -len(".camera")]] = read_strecha(os.path.join(dataset, "gt", f))
    centres, pts = read_our_model(ours)
    common = [n for n in gt if n in centres]
    s, r, t = umeyama(np.array([centres[n] for n in common]), np.array([gt[n][2] for n in common]))
    pts = (s * (r @ pts.T)).T + t
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "cameras.txt"), "w") as fc, open(os.path.join(out, "images.txt"), "w") as fi:
        for i, (name, (k, rwc, c, w, h)) in enumerate(sorted(gt.items()), start=1):
            # Strecha's principal point has the top-left pixel centre at 0; COLMAP's at 0.5.
            fc.write(f"{i} PINHOLE {w} {h} {k[0,0]} {k[1,1]} {k[0,2] + 0.5} {k[1,2] + 0.5}\n")
            rcw = rwc.T
            q = rot_to_quat(rcw)
            tr = -rcw @ c
            fi.write(f"{i} {q[0]} {q[1]} {q[2]} {q[3]} {tr[0]} {tr[1]} {tr[2]} {i} {name}\n\n")
    with open(os.path.join(out, "points3D.txt"), "w") as fp:
        for j, p in enumerate(pts, start=1):
            fp.write(f"{j} {p[0]} {p[1]} {p[2]} 128 128 128 0\n")
    print(f"{len(gt)} GT cameras, {len(pts)} points (scale {s:.4f} from {len(common)} centres)")


if __name__ == "__main__":
    main()
