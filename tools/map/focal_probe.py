#!/usr/bin/env python3
"""Is a sequence's focal length (or its depth scale) what makes its poses disagree with its depth?

For the pairs of pose_depth_consistency.py (keyframes every 5 frames, live frames +-10, +-20), the
keyframe's ground-truth depth is warped into the live frame with the **given** pose (not refined),
with the focal length scaled by s_f (fx and fy, principal point kept; the depth back-projected and
projected with the same scaled K) and the depth scaled by s_d, and the grey-level error (after a
per-pair gain and offset) is averaged over the pairs on a grid of (s_f, s_d). A wrong focal length
would show as one (s_f, s_d) that lowers the error of most pairs; pose errors that differ from pair to
pair as per-pair optima scattered over the grid.

    tools/map/focal_probe.py SEQ

Needs numpy and Pillow. Prints one line per pair (its best grid point) and the mean error table.
"""
import functools
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pose_depth_consistency import blur, grey_error, load_sequence, usable  # noqa: E402
from pose_depth_consistency import pairs as keyframe_pairs  # noqa: E402

FOCAL = [0.90, 0.93, 0.95, 0.97, 1.0, 1.03, 1.05, 1.07, 1.10]
DEPTH = [0.95, 1.0, 1.05, 1.10]


def main():
    seq = sys.argv[1]
    k0, poses, names, dnames = load_sequence(seq)

    @functools.lru_cache(maxsize=None)
    def grey(i):
        return blur(np.array(Image.open(os.path.join(seq, "images", names[i])).convert("L"), dtype=float))

    total = np.zeros((len(FOCAL), len(DEPTH)))
    pairs = 0

    @functools.lru_cache(maxsize=1)
    def depth_of(kf):
        return np.array(Image.open(os.path.join(seq, "depth", dnames[kf])), dtype=float) / 1000.0

    for kf, j, t0 in keyframe_pairs(poses, 5, (-20, -10, 10, 20)):
        depth, ref = depth_of(kf), grey(kf)
        yy, xx = np.mgrid[0: ref.shape[0], 0: ref.shape[1]]
        m = usable(ref, depth)
        err = np.zeros_like(total)
        for a, sf in enumerate(FOCAL):
            kk = k0.copy()
            kk[0, 0] *= sf
            kk[1, 1] *= sf
            rays = np.linalg.inv(kk) @ np.stack([xx[m], yy[m], np.ones(m.sum())])
            for b, sd in enumerate(DEPTH):
                err[a, b] = grey_error(kk, t0, rays * (depth[m] * sd), ref[m], grey(j))
        ia, ib = np.unravel_index(np.nanargmin(err), err.shape)
        ang = np.degrees(np.arccos(np.clip((np.trace(t0[:3, :3]) - 1) / 2, -1, 1)))
        print(f"key {kf:3d} live {j:3d}: rotation {ang:4.1f} deg, |t| {100 * np.linalg.norm(t0[:3, 3]):4.1f} cm, "
              f"error {err[FOCAL.index(1.0), DEPTH.index(1.0)]:.2f} as given, best f x{FOCAL[ia]:.2f} "
              f"depth x{DEPTH[ib]:.2f}: {err[ia, ib]:.2f}", flush=True)
        total += err
        pairs += 1
    print(f"{seq}: {pairs} pairs; mean grey error, rows focal scale {FOCAL}, columns depth scale {DEPTH}")
    for a, sf in enumerate(FOCAL):
        print(f"  f x{sf:.2f}: " + "  ".join(f"{total[a, b] / pairs:6.2f}" for b in range(len(DEPTH))))


if __name__ == "__main__":
    main()
