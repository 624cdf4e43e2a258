#!/usr/bin/env python3
"""Renders a coloured binary PLY point cloud (x y z float, r g b uchar) from the front and from
above, in its principal axes, to look for outlier layers behind or in front of a surface.
Prints the fraction of points farther than 2% / 5% of the cloud extent from a robust local
surface (the median depth of their neighbourhood in the front view).

usage: cloud_views.py CLOUD.ply OUT.png
"""
import sys

import numpy as np
from PIL import Image


def read_ply(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    n = int([l for l in header.splitlines() if l.startswith("element vertex")][0].split()[2])
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    v = np.frombuffer(data[end:end + n * dt.itemsize], dtype=dt)
    return np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64), np.stack([v["r"], v["g"], v["b"]], 1)


def main():
    pts, col = read_ply(sys.argv[1])
    c = np.median(pts, 0)
    q = pts - c
    _, _, vt = np.linalg.svd(q[np.random.default_rng(0).choice(len(q), min(len(q), 200000), replace=False)], full_matrices=False)
    a = q @ vt.T  # a[:,0], a[:,1] span the surface; a[:,2] is depth
    lo, hi = np.percentile(a, 1, 0), np.percentile(a, 99, 0)
    extent = np.linalg.norm(hi - lo)
    size = 800

    def splat(u, v, colors, w, h):
        img = np.zeros((h, w, 3), np.uint8)
        ui = np.clip(((u - u.min()) / (np.ptp(u) + 1e-12) * (w - 1)).astype(int), 0, w - 1)
        vi = np.clip(((v - v.min()) / (np.ptp(v) + 1e-12) * (h - 1)).astype(int), 0, h - 1)
        img[vi, ui] = colors
        return img

    keep = np.all((a >= lo - 0.1 * (hi - lo)) & (a <= hi + 0.1 * (hi - lo)), 1)
    b, cc = a[keep], col[keep]
    front = splat(b[:, 0], b[:, 1], cc, size, int(size * np.ptp(b[:, 1]) / np.ptp(b[:, 0])))
    top = splat(b[:, 0], b[:, 2], cc, size, max(50, int(size * np.ptp(b[:, 2]) / np.ptp(b[:, 0]))))
    h = front.shape[0] + top.shape[0] + 10
    out = np.zeros((h, size, 3), np.uint8)
    out[: front.shape[0]] = front
    out[front.shape[0] + 10:] = top
    Image.fromarray(out).save(sys.argv[2])
    # Local surface test: bin the front view into cells, compare each point's depth to the cell median.
    cell = extent / 200
    keys = np.floor(b[:, :2] / cell).astype(np.int64)
    key = keys[:, 0] * 100003 + keys[:, 1]
    order = np.argsort(key)
    ks, ds = key[order], b[order, 2]
    starts = np.r_[0, np.nonzero(np.diff(ks))[0] + 1, len(ks)]
    dev = np.empty(len(ds))
    for s, e in zip(starts[:-1], starts[1:]):
        dev[s:e] = np.abs(ds[s:e] - np.median(ds[s:e]))
    print(f"points {len(pts)}, extent {extent:.3f}, off the local surface by >2%: {np.mean(dev > 0.02 * extent) * 100:.2f} %, >5%: {np.mean(dev > 0.05 * extent) * 100:.2f} %")


if __name__ == "__main__":
    main()
