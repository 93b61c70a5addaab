#!/usr/bin/env python3
"""Write a real posed sequence (DeepVideoMVS layout: images/, poses.txt camera-to-world, K.txt in
densefeat's pixel-centre convention) as a COLMAP text model with one PINHOLE camera per image, as
COLMAP's image_undistorter writes one: every odd frame is cropped (its own size and principal point),
even frames keep the full image. Used to check the per-frame camera path on real images (issue 34).

    tools/checks/colmap_per_image_cameras.py SRC_SEQUENCE OUT_DIR
"""
import os
import shutil
import sys

import numpy as np
from PIL import Image


def quat_wxyz(r):
    """Hamilton quaternion (w, x, y, z) of a rotation matrix."""
    t = np.trace(r)
    if t > 0:
        s = 2.0 * np.sqrt(t + 1.0)
        return np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
    q = np.zeros(4)
    q[0] = (r[k, j] - r[j, k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (r[j, i] + r[i, j]) / s
    q[1 + k] = (r[k, i] + r[i, k]) / s
    return q


def main(src, out):
    k = np.loadtxt(os.path.join(src, "K.txt"))
    poses = np.loadtxt(os.path.join(src, "poses.txt")).reshape(-1, 4, 4)
    names = sorted(os.listdir(os.path.join(src, "images")))
    os.makedirs(os.path.join(out, "images"), exist_ok=True)
    os.makedirs(os.path.join(out, "sparse", "0"), exist_ok=True)
    cams, imgs = [], []
    for i, (name, t_wc) in enumerate(zip(names, poses)):
        img = Image.open(os.path.join(src, "images", name))
        w, h = img.size
        x0, y0 = (0, 0)
        stem = os.path.splitext(name)[0]
        if i % 2 == 1:
            # A crop whose margins vary per frame: its own size and principal point.
            x0, y0 = 8 + 4 * (i % 5), 6 + 3 * (i % 7)
            x1, y1 = w - 12 - 2 * (i % 3), h - 10 - 2 * (i % 4)
            img = img.crop((x0, y0, x1, y1))
            out_name = stem + ".png"
            img.save(os.path.join(out, "images", out_name))
        else:
            out_name = name
            shutil.copyfile(os.path.join(src, "images", name), os.path.join(out, "images", out_name))
        cw, ch = img.size
        # COLMAP's principal point: densefeat's plus 0.5 (top-left pixel centre at (0.5, 0.5)).
        cams.append(f"{i + 1} PINHOLE {cw} {ch} {float(k[0, 0])!r} {float(k[1, 1])!r} {float(k[0, 2] - x0 + 0.5)!r} {float(k[1, 2] - y0 + 0.5)!r}")
        t_cw = np.linalg.inv(t_wc)
        q = quat_wxyz(t_cw[:3, :3])
        t = t_cw[:3, 3]
        imgs.append(f"{i + 1} {float(q[0])!r} {float(q[1])!r} {float(q[2])!r} {float(q[3])!r} {float(t[0])!r} {float(t[1])!r} {float(t[2])!r} {i + 1} {out_name}")
        imgs.append("")
    with open(os.path.join(out, "sparse", "0", "cameras.txt"), "w") as f:
        f.write("# one PINHOLE camera per image\n" + "\n".join(cams) + "\n")
    with open(os.path.join(out, "sparse", "0", "images.txt"), "w") as f:
        f.write("# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then an empty 2D-point line\n")
        f.write("\n".join(imgs) + "\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
