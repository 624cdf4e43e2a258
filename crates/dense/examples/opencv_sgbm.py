#!/usr/bin/env python3
"""Reference timing/accuracy of OpenCV StereoSGBM on a rectified Middlebury pair.

Usage: opencv_sgbm.py LEFT.png RIGHT.png OUT.pfm [--runs 5]
Settings as in ../shared/datasets/README.md: 64 disparities (0..63), block size 5,
P1 = 8*3*5^2, P2 = 32*3*5^2, MODE_SGBM. Prints one JSON line (method, width, height,
seconds = median of the runs, density). OUT.pfm is little-endian, rows bottom to top,
invalid = NaN, so ../shared/tools/eval_stereo.py can score it.
"""
import json
import sys
import time

import cv2
import numpy as np


def write_pfm(path, d):
    h, w = d.shape
    with open(path, "wb") as f:
        f.write(b"Pf\n%d %d\n-1\n" % (w, h))
        np.flipud(d).astype("<f4").tofile(f)


def main():
    args = sys.argv[1:]
    runs = 5
    if "--runs" in args:
        i = args.index("--runs")
        runs = int(args[i + 1])
        del args[i:i + 2]
    left_p, right_p, out_p = args
    left = cv2.imread(left_p, cv2.IMREAD_COLOR)
    right = cv2.imread(right_p, cv2.IMREAD_COLOR)
    bs = 5
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=64, blockSize=bs,
                                 P1=8 * 3 * bs * bs, P2=32 * 3 * bs * bs,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM)
    times = []
    disp = None
    for _ in range(runs):
        t0 = time.perf_counter()
        disp = sgbm.compute(left, right)
        times.append(time.perf_counter() - t0)
    d = disp.astype(np.float32) / 16.0
    d[d < 0] = np.nan
    write_pfm(out_p, d)
    valid = np.isfinite(d) & (d > 0)
    print(json.dumps(dict(method="opencv-sgbm", threads=cv2.getNumThreads(),
                          width=int(d.shape[1]), height=int(d.shape[0]),
                          seconds=round(float(np.median(times)), 4),
                          density=round(float(100 * valid.mean()), 2))))


if __name__ == "__main__":
    main()
