#!/usr/bin/env python3
"""Winner-take-all depth accuracy by pixel category: blank pixels, blank pixels beside a nearer
surface, textured pixels. Reads `densefeat eval --save-depth` outputs. Used in docs/table1/README.md
("The blank wall on the training scenes").

    python3 tools/paper/blank_categories.py SEQUENCE:EVAL_DIR [SEQUENCE:EVAL_DIR ...]

For every keyframe folder `EVAL_DIR/kf_NNNNN_KIND/` with `depth_wta.npy`, against the ground truth
`SEQUENCE/depth/NNNNN.png` (millimetres; 0 = none) and the keyframe `SEQUENCE/images/NNNNN.png`:
- texture t = the 9x9 box mean of the grey image's Sobel gradient magnitude; blank: t < 20 (grey
  levels per pixel, Sobel's scale; on validation scene s200001's keyframe 20 the grey wall's median
  is 3.5 and its checkerboard wall's 62);
- beside a nearer surface: the 33x33 window around the pixel holds a depth below 0.8 of its own
  (a background pixel within 16 px of an occluding edge).
- leaving a frame: the pixel's true match (its ground-truth depth through poses.txt, camera-to-world,
  and K.txt) lies outside the image of some frame within 30 of the keyframe (eval's default window).
Prints one line per keyframe and method: δ<1.25 of the WTA depth over all pixels with ground truth,
blank pixels away from an occluder, blank pixels beside one, textured pixels, and blank pixels whose
true match stays inside every frame / leaves some frame (in brackets each category's share of the
pixels with ground truth).
"""
import glob
import os
import sys

import numpy as np
from PIL import Image
from scipy.ndimage import minimum_filter, sobel, uniform_filter

BLANK_TEXTURE = 20.0
OCCLUDER_RADIUS = 16
OCCLUDER_RATIO = 0.8


def categories(seq, frame):
    z = np.array(Image.open(f"{seq}/depth/{frame}.png")).astype(float) / 1000.0
    valid = z > 0
    z[~valid] = np.inf
    grey = np.array(Image.open(f"{seq}/images/{frame}.png").convert("L")).astype(float)
    texture = uniform_filter(np.hypot(sobel(grey, 0), sobel(grey, 1)), 9)
    blank = texture < BLANK_TEXTURE
    near = minimum_filter(z, size=2 * OCCLUDER_RADIUS + 1) < OCCLUDER_RATIO * z
    leaving = leaves_a_frame(seq, int(frame), z, valid)
    return z, {
        "all": valid,
        "blank": valid & blank & ~near,
        "blank beside an occluder": valid & blank & near,
        "textured": valid & ~blank,
        "blank, match in every frame": valid & blank & ~leaving,
        "blank, match leaves a frame": valid & blank & leaving,
    }


def leaves_a_frame(seq, kf, z, valid, window=30):
    """Pixels whose true match lies outside the image (or behind the camera) of some frame within
    `window` of keyframe `kf`."""
    poses = np.loadtxt(f"{seq}/poses.txt").reshape(-1, 4, 4)
    k = np.loadtxt(f"{seq}/K.txt")
    h, w = z.shape
    ys, xs = np.nonzero(valid)
    out = np.zeros(xs.size, bool)
    for n in range(max(0, kf - window), min(len(poses), kf + window + 1)):
        if n != kf:
            out |= ~match_inside(k, poses[kf], np.linalg.inv(poses[n]), xs, ys, z[ys, xs], w, h)
    mask = np.zeros_like(valid)
    mask[ys, xs] = out
    return mask


def match_inside(k, c2w_ref, w2c_live, xs, ys, depth, w, h):
    """Whether reference pixels (xs, ys) at `depth` (camera K `k`, both cameras `w x h`) project in
    front of the live camera and inside its image."""
    rays = np.linalg.solve(k, np.stack([xs, ys, np.ones(xs.size)]).astype(float))
    world = c2w_ref[:3, :3] @ (rays * depth) + c2w_ref[:3, 3:4]
    uvw = k @ (w2c_live[:3, :3] @ world + w2c_live[:3, 3:4])
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = uvw[0] / uvw[2], uvw[1] / uvw[2]
    return (uvw[2] > 0) & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)


def main(argv):
    if not argv:
        sys.exit(__doc__)
    for arg in argv:
        seq, _, out = arg.partition(":")
        if not out:
            sys.exit(f"blank_categories.py: {arg!r}: expected SEQUENCE:EVAL_DIR")
        kfs = sorted(glob.glob(f"{out}/kf_*_*/depth_wta.npy"))
        if not kfs:
            sys.exit(f"blank_categories.py: {out}: no kf_*/depth_wta.npy (run eval with --save-depth)")
        for path in kfs:
            folder = os.path.basename(os.path.dirname(path))
            _, frame, kind = folder.split("_", 2)
            z, cats = categories(seq, frame)
            wta = np.load(path).astype(float)
            with np.errstate(divide="ignore", invalid="ignore"):
                ok = np.maximum(wta / z, z / wta) < 1.25
            n = cats["all"].sum()
            cells = []
            for name, m in cats.items():
                share = m.sum() / n
                cells.append(f"{name} {ok[m].mean():.3f} ({share:.3f})" if m.any() else f"{name} - (0)")
            print(f"{os.path.basename(seq.rstrip('/'))} kf {frame} {kind} [{out}]: " + " | ".join(cells))


if __name__ == "__main__":
    main(sys.argv[1:])
