#!/usr/bin/env python3
"""Which views of a sparse model are misplaced: the model's rotations (COLMAP text) against the
ground truth's, after the world rotation of one view that puts the most views within the bound (so
the figures are a little above those of a least-squares alignment). Prints how many agree, the
median and largest error, and every view beyond the bound with its error in degrees. Rotations only, so it needs no
scale or centre alignment.

    scripts/view_errors.py WORKSPACE/sparse DEMO/ground_truth/sparse [--bound-deg 1]
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from gt_pairs import read_poses  # noqa: E402


def angle_deg(r):
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model")
    ap.add_argument("gt_sparse")
    ap.add_argument("--bound-deg", type=float, default=1.0)
    a = ap.parse_args()
    model = {n: r for n, (r, _) in read_poses(a.model).items()}
    gt = {n: r for n, (r, _) in read_poses(a.gt_sparse).items()}
    names = sorted(n for n in model if n in gt)
    best = None
    for n in names:
        world = gt[n].T @ model[n]  # R_model = R_gt · world
        errors = [angle_deg(model[k] @ (gt[k] @ world).T) for k in names]
        agree = sum(e < a.bound_deg for e in errors)
        if best is None or agree > best[0]:
            best = (agree, errors)
    errors = sorted(best[1])
    print(f"{best[0]} of {len(names)} registered views within {a.bound_deg}° (of {len(gt)} in the ground truth); "
          f"rotation error median {errors[len(errors) // 2]:.3f}°, max {errors[-1]:.3f}°")
    for n, e in zip(names, best[1]):
        if e >= a.bound_deg:
            print(f"{n}: {e:.2f}°")


if __name__ == "__main__":
    main()
