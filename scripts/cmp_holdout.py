#!/usr/bin/env python3
"""Two hold-out renders of the same view compared over the same pixels.

The mesh stage's `--hold-out` figure is a mean colour difference over the pixels the model
covers, so two models that cover different pixels are not compared like for like: a model that
leaves a hard region open (a gap between columns) scores as well as one that draws it a little
off. This reads two `holdout.png` strips (rendering | photo | 4x difference, with uncovered
pixels drawn (0, 0, 60)) and prints each model's figure over its own pixels, over the pixels
both cover, and over the pixels only one covers.

    scripts/cmp_holdout.py A/mesh/holdout.png B/mesh/holdout.png [--mask OUT.png]

`--mask` writes the photo at half brightness with the pixels only A covers in green and those
only B covers in red.
"""
import argparse

import numpy as np
from PIL import Image

UNCOVERED = (0, 0, 60)


def load(path):
    """(covered mask, per-pixel mean absolute colour difference, photo) of one strip."""
    a = np.asarray(Image.open(path).convert("RGB")).astype(np.int32)
    if a.shape[1] % 3:
        raise SystemExit(f"{path}: not a hold-out strip (its width is not three images)")
    w = a.shape[1] // 3
    render, photo, diff = a[:, :w], a[:, w : 2 * w], a[:, 2 * w :]
    covered = ~np.all(diff == np.array(UNCOVERED), axis=2)
    err = np.abs(render - photo).mean(axis=2)
    return covered, err, photo


def mean_over(err, mask):
    return float(err[mask].mean()) if mask.any() else float("nan")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--mask", help="write where the two coverages differ (A only green, B only red)")
    args = p.parse_args()
    ca, ea, photo = load(args.a)
    cb, eb, _ = load(args.b)
    if ca.shape != cb.shape:
        raise SystemExit(f"the strips differ in size: {ca.shape} and {cb.shape}")
    both, a_only, b_only = ca & cb, ca & ~cb, cb & ~ca
    pct = lambda m: 100.0 * m.mean()  # noqa: E731
    print(f"A: {mean_over(ea, ca):.2f} over {pct(ca):.1f} %   B: {mean_over(eb, cb):.2f} over {pct(cb):.1f} %")
    print(f"both cover {pct(both):.1f} %: A {mean_over(ea, both):.2f}, B {mean_over(eb, both):.2f}")
    print(
        f"A only {pct(a_only):.2f} %: {mean_over(ea, a_only):.2f};  "
        f"B only {pct(b_only):.2f} %: {mean_over(eb, b_only):.2f}"
    )
    if args.mask:
        out = (photo // 2).astype(np.uint8)
        out[a_only] = (0, 255, 0)
        out[b_only] = (255, 0, 0)
        Image.fromarray(out).save(args.mask)


if __name__ == "__main__":
    main()
