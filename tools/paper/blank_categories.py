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
Prints one line per keyframe and method: δ<1.25 of the WTA depth over all pixels with ground truth,
blank pixels away from an occluder, blank pixels beside one, textured pixels (in brackets each
category's share of the pixels with ground truth).
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
    return z, {
        "all": valid,
        "blank": valid & blank & ~near,
        "blank beside an occluder": valid & blank & near,
        "textured": valid & ~blank,
    }


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
