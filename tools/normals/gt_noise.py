#!/usr/bin/env python3
"""How noisy are ground-truth normals taken from a sensor's depth? (SPEC.md §10.2, `--normals gt`)

For frames of DeepVideoMVS-layout sequences (K.txt, depth/NNNNN.png in millimetres), compares the
normals of central differences over +-2 pixels (the `gt` rule until 2026-12-06) with those of the
inverse-depth plane fit `gt` uses now (window radius round(3 f / 256), 5 % depth gate), and prints
the mean and median angle between the two. On exact rendered depth both are exact on planes and
differ only at edges and creases; on a real sensor's depth the difference is the stencil's noise.

    python3 tools/normals/gt_noise.py SEQ [SEQ ...] [--frames 0,25,49] [--depth-scale 1000] [--plot OUT.png]

With --plot, OUT.png shows each sequence's first listed frame: the image, the old rule's normals and
the fit's (camera-frame normals as colours, (n + 1)/2 in RGB; black: none).
"""
import argparse
import os

import numpy as np
from PIL import Image


def points(z, K):
    h, w = z.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)


def orient(n, X):
    s = np.where((n * X).sum(-1) > 0, -1.0, 1.0)
    return n * s[..., None]


def central(z, K, s=2):
    X = points(z, K)
    valid = z > 0
    h, w = z.shape
    n = np.full(X.shape, np.nan)
    ok = np.zeros_like(valid)
    ok[s:-s, s:-s] = (valid[s:-s, 2 * s:] & valid[s:-s, :-2 * s] & valid[2 * s:, s:-s]
                      & valid[:-2 * s, s:-s] & valid[s:-s, s:-s])
    tx = X[s:-s, 2 * s:] - X[s:-s, :-2 * s]
    ty = X[2 * s:, s:-s] - X[:-2 * s, s:-s]
    c = np.cross(tx, ty)
    n[s:-s, s:-s] = c / np.linalg.norm(c, axis=-1, keepdims=True)
    n[~ok] = np.nan
    return orient(n, X)


def fit(z, K, gate=0.05):
    r = max(1, round(3 * min(abs(K[0, 0]), abs(K[1, 1])) / 256))
    h, w = z.shape
    valid = z > 0
    rho = np.where(valid, 1 / np.where(valid, z, 1), 0)
    sums = {k: np.zeros((h, w)) for k in ("n", "u", "v", "uu", "uv", "vv", "r", "ur", "vr")}
    zp, rp = np.pad(z, r), np.pad(rho, r)
    for dv in range(-r, r + 1):
        for du in range(-r, r + 1):
            zn = zp[r + dv:r + dv + h, r + du:r + du + w]
            m = ((zn > 0) & valid & (np.abs(zn - z) <= gate * z)).astype(float)
            rn = rp[r + dv:r + dv + h, r + du:r + du + w] * m
            sums["n"] += m; sums["u"] += du * m; sums["v"] += dv * m
            sums["uu"] += du * du * m; sums["uv"] += du * dv * m; sums["vv"] += dv * dv * m
            sums["r"] += rn; sums["ur"] += du * rn; sums["vr"] += dv * rn
    S = np.stack([np.stack([sums["n"], sums["u"], sums["v"]], -1),
                  np.stack([sums["u"], sums["uu"], sums["uv"]], -1),
                  np.stack([sums["v"], sums["uv"], sums["vv"]], -1)], -2)
    t = np.stack([sums["r"], sums["ur"], sums["vr"]], -1)
    good = valid & (sums["n"] >= max(6, -(-(2 * r + 1) ** 2 // 4))) & (np.linalg.det(S) >= 0.5)
    S[~good] = np.eye(3)
    p = np.linalg.solve(S, t[..., None])[..., 0]
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    a, b, c = p[..., 0], p[..., 1], p[..., 2]
    n = np.stack([K[0, 0] * b, K[1, 1] * c, a + b * (K[0, 2] - u) + c * (K[1, 2] - v)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[~good] = np.nan
    return orient(n, points(z, K)), r


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("seqs", nargs="+")
    ap.add_argument("--frames", default="0,25,49")
    ap.add_argument("--depth-scale", type=float, default=1000.0)
    ap.add_argument("--plot")
    args = ap.parse_args()
    panels = []
    print("| sequence | frames | window | mean / median angle, central ±2 px vs fit |")
    print("|---|---|---|---|")
    for seq in args.seqs:
        K = np.loadtxt(os.path.join(seq, "K.txt"))
        names = sorted(os.listdir(os.path.join(seq, "depth")))
        angles, used, r = [], [], 0
        for f in (int(x) for x in args.frames.split(",")):
            if f >= len(names):
                continue
            z = np.asarray(Image.open(os.path.join(seq, "depth", names[f]))).astype(np.float64) / args.depth_scale
            nc = central(z, K)
            nf, r = fit(z, K)
            c = np.clip((nc * nf).sum(-1), -1, 1)
            d = np.degrees(np.arccos(c))
            angles.append(d[np.isfinite(d)])
            used.append(names[f])
            if args.plot and len(used) == 1:
                image = sorted(os.listdir(os.path.join(seq, "images")))[f]
                rgb = np.asarray(Image.open(os.path.join(seq, "images", image)).convert("RGB"))
                panels.append((os.path.basename(os.path.normpath(seq)), names[f], rgb, nc, nf, r))
        a = np.concatenate(angles)
        print(f"| {os.path.basename(os.path.normpath(seq))} | {', '.join(used)} | {2 * r + 1}x{2 * r + 1} | "
              f"{a.mean():.1f}° / {np.median(a):.1f}° |")
    if args.plot:
        plot(panels, args.plot)


def colour(n):
    c = (np.nan_to_num(n, nan=-1.0) + 1) / 2
    return np.clip(c, 0, 1)


def plot(panels, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(panels), 3, figsize=(12, 3.2 * len(panels)), squeeze=False)
    for row, (name, frame, rgb, nc, nf, r) in zip(axes, panels):
        d = np.degrees(np.arccos(np.clip((nc * nf).sum(-1), -1, 1)))
        d = d[np.isfinite(d)]
        row[0].imshow(rgb)
        row[0].set_title(f"{name} {frame}", fontsize=9)
        row[1].imshow(colour(nc))
        row[1].set_title("central differences, ±2 px (before)", fontsize=9)
        row[2].imshow(colour(nf))
        row[2].set_title(f"inverse-depth plane fit, {2 * r + 1}x{2 * r + 1} (now); "
                         f"{d.mean():.1f}° apart (mean)", fontsize=9)
        for ax in row:
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(out, dpi=60)


if __name__ == "__main__":
    main()
