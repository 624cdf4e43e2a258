#!/usr/bin/env python3
"""Phone-like variants of a data set with Strecha ground truth (DS/images/*.jpg, DS/gt/*.camera),
made with ffmpeg, each a data set of its own with its ground truth moved along:

  portrait  every image turned 90° clockwise (a phone held upright), K and R turned with it;
  crop16x9  the centre cut to a phone's 16:9 aspect (the principal point moves with the crop);
  k1        radial distortion added (ffmpeg's lenscorrection, k1 = -0.03 on the half-diagonal:
            about +0.07 in eq. 3's units for fountain, pincushion like the phone of issue #37).

    scripts/phone_variants.py ../shared/datasets/fountain-P11 OUT

then, for each variant V: handheld reconstruct OUT/V/images -o WS --until sparse and
python3 ../shared/tools/eval_sfm.py WS/sparse OUT/V.
"""
import glob
import os
import subprocess
import sys

import numpy as np


def read_camera(path):
    v = open(path).read().split()
    k = np.array(v[0:9], float).reshape(3, 3)
    rest = np.array(v[9:12], float)
    rcw = np.array(v[12:21], float).reshape(3, 3)
    c = np.array(v[21:24], float)
    w, h = int(v[24]), int(v[25])
    return k, rest, rcw, c, w, h


def write_camera(path, k, rest, rcw, c, w, h):
    rows = [" ".join(f"{x:.10g}" for x in r) for r in k]
    rows.append(" ".join(f"{x:.10g}" for x in rest))
    rows += [" ".join(f"{x:.10g}" for x in r) for r in rcw]
    rows.append(" ".join(f"{x:.10g}" for x in c))
    rows.append(f"{w} {h}")
    open(path, "w").write("\n".join(rows) + "\n")


def ffmpeg(src, dst, vf):
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", src, "-vf", vf, "-q:v", "2", dst], check=True)


def main():
    ds, out = sys.argv[1], sys.argv[2]
    cams = sorted(glob.glob(os.path.join(ds, "gt", "*.camera")))
    if not cams:
        sys.exit(f"{ds}/gt has no *.camera files")
    for variant in ["portrait", "crop16x9", "k1"]:
        os.makedirs(os.path.join(out, variant, "images"), exist_ok=True)
        os.makedirs(os.path.join(out, variant, "gt"), exist_ok=True)
    for cam in cams:
        name = os.path.basename(cam)[: -len(".camera")]
        src = os.path.join(ds, "images", name)
        k, rest, rcw, c, w, h = read_camera(cam)
        # Portrait: 90° clockwise, u' = (h - 1) - v, v' = u; camera axes x' = -y, y' = x.
        rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        kp = np.array([[k[1, 1], 0, (h - 1) - k[1, 2]], [0, k[0, 0], k[0, 2]], [0, 0, 1]])
        ffmpeg(src, os.path.join(out, "portrait", "images", name), "transpose=1")
        write_camera(os.path.join(out, "portrait", "gt", name + ".camera"), kp, rest, rcw @ rz.T, c, h, w)
        # 16:9 crop of the centre.
        ch = (w * 9 // 16) // 2 * 2
        y0 = (h - ch) // 2
        kc = k.copy()
        kc[1, 2] -= y0
        ffmpeg(src, os.path.join(out, "crop16x9", "images", name), f"crop={w}:{ch}:0:{y0}")
        write_camera(os.path.join(out, "crop16x9", "gt", name + ".camera"), kc, rest, rcw, c, w, ch)
        # Radial distortion.
        ffmpeg(src, os.path.join(out, "k1", "images", name), "lenscorrection=cx=0.5:cy=0.5:k1=-0.03:k2=0")
        write_camera(os.path.join(out, "k1", "gt", name + ".camera"), k, rest, rcw, c, w, h)


if __name__ == "__main__":
    main()
