#!/usr/bin/env python3
"""How much the feature network encodes the image position (docs/training/README.md, "The position
code"): `densefeat features` on a constant grey 640x480 image for each weights file, then the L1
distance of every level-1 feature to the centre one, by distance to the border, the mean horizontal
feature gradient, and a picture of the maps.

    python3 tools/train_chain/position_code.py OUT.png NAME=WEIGHTS [NAME=WEIGHTS ...]

BIN=path/to/densefeat selects the binary (default target/release/densefeat).
"""
import os
import subprocess
import sys
import tempfile

import matplotlib
import numpy as np
from PIL import Image

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

BANDS = [(0, 8), (8, 32), (32, 80), (80, 10**9)]


def main():
    out, pairs = sys.argv[1], [a.split("=", 1) for a in sys.argv[2:]]
    if not pairs or any(len(p) != 2 for p in pairs):
        sys.exit(__doc__)
    binary = os.environ.get("BIN", "target/release/densefeat")
    tmp = tempfile.mkdtemp()
    grey = os.path.join(tmp, "grey.png")
    Image.fromarray(np.full((480, 640, 3), 140, np.uint8)).save(grey)
    print("| weights | " + " | ".join(f"[{lo}, {hi if hi < 10**9 else '∞'}) px" for lo, hi in BANDS)
          + " | mean ‖∂f/∂x‖₁ |")
    print("|---" * (len(BANDS) + 2) + "|")
    fig, axes = plt.subplots(1, len(pairs), figsize=(4.7 * len(pairs), 3.8), squeeze=False)
    for ax, (name, weights) in zip(axes[0], pairs):
        npy = os.path.join(tmp, f"{name}.npy")
        subprocess.run([binary, "features", grey, "--weights", weights, "--out", npy],
                       check=True, stdout=subprocess.DEVNULL)
        f = np.load(npy)
        d = np.abs(f - f[f.shape[0] // 2, f.shape[1] // 2]).sum(2)
        h, w = d.shape
        yy, xx = np.mgrid[:h, :w]
        dist = np.minimum(np.minimum(yy, h - 1 - yy), np.minimum(xx, w - 1 - xx))
        bands = [d[(dist >= lo) & (dist < hi)].mean() for lo, hi in BANDS]
        grad = np.abs(f[:, 1:] - f[:, :-1]).sum(2).mean()
        print(f"| {name} | " + " | ".join(f"{b:.2f}" for b in bands) + f" | {grad:.3f} |")
        im = ax.imshow(d, cmap="magma", vmin=0, vmax=12)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{name}\nconstant grey image: L1(f(u) - f(centre)), mean {d.mean():.2f}", fontsize=9)
    plt.colorbar(im, ax=axes[0].tolist(), fraction=0.015)
    plt.savefig(out, dpi=90, bbox_inches="tight")


if __name__ == "__main__":
    main()
