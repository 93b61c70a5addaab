#!/usr/bin/env python3
"""Pack a DeepVideoMVS-layout sequence (images/*.png|jpg, depth/*.png uint16 mm, poses.txt, K.txt)
into a compact folder for tools/train_gpu/train_gpu.py:

  OUT/meta.json      name, K (fx fy cx cy), width, height, frame names, poses (4x4 camera-to-world)
  OUT/NNNNN.jpg      colour: JPEG files copied unchanged, PNG re-encoded as JPEG (--quality)
  OUT/depth.u16.z    every kept frame's depth, uint16 millimetres, row-major, zlib level 9

Usage: python3 tools/train_gpu/pack.py SEQ_DIR OUT_DIR [--every N] [--quality 92]
Only TRAINING scenes of SPEC.md §3a may be packed for training.
"""
import argparse, io, json, shutil, sys, zlib
from pathlib import Path

import numpy as np
from PIL import Image


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seq")
    ap.add_argument("out")
    ap.add_argument("--every", type=int, default=1, help="keep every N-th frame")
    ap.add_argument("--quality", type=int, default=92)
    a = ap.parse_args()
    seq, out = Path(a.seq), Path(a.out)
    images = sorted(p for p in (seq / "images").iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    poses = [list(map(float, l.split())) for l in (seq / "poses.txt").read_text().splitlines() if l.strip()]
    assert len(poses) == len(images), (len(poses), len(images))
    k = [list(map(float, l.split())) for l in (seq / "K.txt").read_text().splitlines() if l.strip()]
    keep = list(range(0, len(images), a.every))
    out.mkdir(parents=True, exist_ok=True)
    depth, names = [], []
    w = h = None
    for i in keep:
        p = images[i]
        name = p.stem
        im = Image.open(p)
        w, h = im.size
        if p.suffix.lower() in (".jpg", ".jpeg"):
            shutil.copyfile(p, out / f"{name}.jpg")
        else:
            im.convert("RGB").save(out / f"{name}.jpg", quality=a.quality)
        d = np.asarray(Image.open(seq / "depth" / f"{name}.png")).astype(np.uint16)
        assert d.shape == (h, w), (d.shape, h, w)
        depth.append(d)
        names.append(name)
    (out / "depth.u16.z").write_bytes(zlib.compress(np.stack(depth).astype("<u2").tobytes(), 9))
    meta = dict(name=seq.name, fx=k[0][0], fy=k[1][1], cx=k[0][2], cy=k[1][2], width=w, height=h,
                frames=names, poses=[[poses[i][r * 4:(r + 1) * 4] for r in range(4)] for i in keep],
                source=str(seq), every=a.every)
    (out / "meta.json").write_text(json.dumps(meta))
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"{seq.name}: {len(keep)} frames {w}x{h} -> {out} ({size / 2**20:.1f} MiB)")


if __name__ == "__main__":
    sys.exit(main())
