#!/usr/bin/env python3
"""The training loss's posterior on a keyframe, by pixel category: what the paper's objective (SPEC.md
§13.1) sees on blank pixels. Used in docs/table1/README.md ("The blank wall on the training scenes").

    python3 tools/paper/pair_posterior.py SEQUENCE REF LIVE[,LIVE...] TAG=WEIGHTS [TAG=WEIGHTS ...]

For each weights file, `densefeat features` gives the level-1 features of the reference and live
frames (runs/posterior/); then, per reference pixel j at level 1 with ground truth (the level-0 depth
at 2j, SPEC §2.6) and hypotheses ρ_l over the paper's 256 bins on [0, 4] 1/m:
  E_l = mean over the live frames of ‖f_ref(j) − f_live(u'_l)‖² (bilinear; 10 outside a frame;
        with COST=l1 in the environment the mapper's L1 over the channels instead),
  P = softmax(−E), l* the bin nearest ρ*.
Only pixels whose true match lies inside every live frame count (as in the loss). Reported per
category (tools/paper/blank_categories.py's, at the pixel 2j): mean P within ±2 bins of l*, mean
−ln P_{l*}, and δ<1.25 of the winner-take-all and of the expected depth 1/Σ P_l ρ_l.
"""
import os
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from blank_categories import categories, match_inside  # noqa: E402

BIN = os.environ.get("BIN", "target/release/densefeat")
RHO = np.linspace(0.0, 4.0, 256)
COST = os.environ.get("COST", "l2")


def features(image, weights, out):
    if not os.path.exists(out):
        subprocess.run([BIN, "features", image, "--weights", weights, "--out", out], check=True,
                       stdout=subprocess.DEVNULL)
    return np.load(out).astype(np.float64)


def bilinear(f, u, v):
    h, w, _ = f.shape
    inside = (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    x0 = np.minimum(np.floor(u).astype(int), w - 2)
    y0 = np.minimum(np.floor(v).astype(int), h - 2)
    a, b = u - x0, v - y0
    s = (f[y0, x0] * ((1 - a) * (1 - b))[..., None] + f[y0, x0 + 1] * (a * (1 - b))[..., None]
         + f[y0 + 1, x0] * ((1 - a) * b)[..., None] + f[y0 + 1, x0 + 1] * (a * b)[..., None])
    return s, inside


def project(k, c2w_ref, w2c_live, x, y, rho):
    """Level-1 pixel (x, y) of the reference at inverse depth rho -> live level-1 pixel, z > 0."""
    ray = np.linalg.solve(k, np.stack([x, y, np.ones_like(x)]))
    pts = ray[:, :, None] / np.maximum(rho[None, None, :], 1e-9)
    world = c2w_ref[:3, :3] @ pts.reshape(3, -1) + c2w_ref[:3, 3:4]
    cam = w2c_live[:3, :3] @ world + w2c_live[:3, 3:4]
    uvw = k @ cam
    z = uvw[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = uvw[0] / z, uvw[1] / z
    shape = (x.size, rho.size)
    return u.reshape(shape), v.reshape(shape), (z > 0).reshape(shape)


def main(argv):
    if len(argv) < 4:
        sys.exit(__doc__)
    seq, ref, lives = argv[0], int(argv[1]), [int(v) for v in argv[2].split(",")]
    poses = np.loadtxt(f"{seq}/poses.txt").reshape(-1, 4, 4)
    k = np.loadtxt(f"{seq}/K.txt")
    k[:2] *= 0.5  # level 1 (SPEC §2.6: fx/2, cx/2)
    frame = f"{ref:05d}"
    z0, cats0 = categories(seq, frame)
    z = z0[::2, ::2]
    cats = {n: m[::2, ::2] for n, m in cats0.items()}
    h, w = z.shape
    ys, xs = np.nonzero(cats["all"])
    rho_star = 1.0 / z[ys, xs]
    target = np.clip(np.rint(rho_star / (4.0 / 255)).astype(int), 0, 255)
    scene = os.path.basename(seq.rstrip("/"))
    for tw in argv[3:]:
        tag, _, wpath = tw.partition("=")
        d = f"runs/posterior/{scene}_{tag}"
        os.makedirs(d, exist_ok=True)
        fr = features(f"{seq}/images/{frame}.png", wpath, f"{d}/{frame}.npy")
        fl = [features(f"{seq}/images/{n:05d}.png", wpath, f"{d}/{n:05d}.npy") for n in lives]
        if fr.shape[:2] != (h, w):
            sys.exit(f"pair_posterior.py: features {fr.shape} are not at level 1 of {z0.shape}")
        energy = np.zeros((xs.size, RHO.size))
        keep = np.ones(xs.size, bool)
        for n, f in zip(lives, fl):
            u, v, front = project(k, poses[ref], np.linalg.inv(poses[n]), xs.astype(float), ys.astype(float), RHO)
            for s in range(0, xs.size, 2000):
                sl = slice(s, s + 2000)
                sample, inside = bilinear(f, u[sl], v[sl])
                inside &= front[sl]
                diff = fr[ys[sl], xs[sl]][:, None, :] - sample
                e = np.abs(diff).sum(-1) if COST == "l1" else (diff ** 2).sum(-1)
                energy[sl] += np.where(inside, e, 10.0)
            # The true match inside this frame (the loss's mask).
            keep &= match_inside(k, poses[ref], np.linalg.inv(poses[n]), xs, ys, 1.0 / rho_star, w, h)
        energy /= len(lives)
        e = -energy
        e -= e.max(1, keepdims=True)
        p = np.exp(e)
        p /= p.sum(1, keepdims=True)
        idx = np.arange(xs.size)
        near = sum(p[idx, np.clip(target + o, 0, 255)] for o in range(-2, 3))
        nll = -np.log(np.maximum(p[idx, target], 1e-300))
        wta = 1.0 / np.maximum(RHO[energy.argmin(1)], 1e-9)
        exp_d = 1.0 / np.maximum((p * RHO).sum(1), 0.1)
        zt = 1.0 / rho_star
        ok_w = np.maximum(wta / zt, zt / wta) < 1.25
        ok_e = np.maximum(exp_d / zt, zt / exp_d) < 1.25
        cells = []
        for name, m in cats.items():
            sel = m[ys, xs] & keep
            if sel.any():
                cells.append(f"{name}: P±2 {near[sel].mean():.3f}, -lnP* {nll[sel].mean():.2f}, "
                             f"wta {ok_w[sel].mean():.3f}, exp {ok_e[sel].mean():.3f} ({sel.sum()})")
        print(f"{scene} ref {ref} lives {argv[2]} {tag}: " + " | ".join(cells))


if __name__ == "__main__":
    main(sys.argv[1:])
