#!/usr/bin/env python3
"""Temporal selection against the mapper's mean, on one keyframe (docs/table1/README.md, "Session 44").

    python3 tools/paper/temporal_selection.py SEQUENCE REF WEIGHTS [STRIDE]

The learned features' level-1 cost (`densefeat features`, SPEC.md §9: L1 over the 32 channels,
bilinear sampling) of every STRIDE-th level-1 keyframe pixel with ground truth, over 128 hypotheses
uniform in inverse depth on [0.1, 2.5] 1/m (eval's default range and bins), against every frame within
30 of REF (eval's window). Per hypothesis, aggregated over the frames that see it as
  mean      the mapper's rule (SPEC.md §9.10; the evidence minimum 0.25 of the pixel's most-seen cell),
  bestF     the mean of the lowest ceil(F n) of the n frames' costs (Kang, Szeliski and Chai's
            temporal selection), F = 0.75, 0.5, 0.3,
  median    the median of the n costs,
and the winner-take-all's δ<1.25 is printed per pixel category (tools/paper/blank_categories.py). Then,
for the mapper's rule, the curves' minimum and minimum/median (1 minus §9.12's sharpness) on the pixels
it gets right and wrong, and how well each separates the two (AUC: the chance that a wrong pixel has the
larger value than a right one).
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from blank_categories import categories  # noqa: E402
from pair_posterior import bilinear, features, project  # noqa: E402

RHO = np.linspace(0.1, 2.5, 128)


def auc(score, wrong):
    """P(score of a wrong pixel > score of a right one), ties half (rank-sum)."""
    ranks = np.argsort(np.argsort(score, kind="stable"), kind="stable") + 1.0
    nw, nr = wrong.sum(), (~wrong).sum()
    return (ranks[wrong].sum() - nw * (nw + 1) / 2) / (nw * nr)


def main(argv):
    if len(argv) < 3:
        sys.exit(__doc__)
    seq, ref, wpath = argv[0], int(argv[1]), argv[2]
    stride = int(argv[3]) if len(argv) > 3 else 2
    poses = np.loadtxt(f"{seq}/poses.txt").reshape(-1, 4, 4)
    k = np.loadtxt(f"{seq}/K.txt")
    k[:2] *= 0.5  # level 1 (SPEC §2.6)
    frame = f"{ref:05d}"
    z0, cats0 = categories(seq, frame)
    z = z0[::2, ::2]
    cats = {n: m[::2, ::2] for n, m in cats0.items()}
    grid = np.zeros_like(cats["all"])
    grid[::stride, ::stride] = True
    ys, xs = np.nonzero(cats["all"] & grid)
    lives = [n for n in range(max(0, ref - 30), min(len(poses), ref + 31)) if n != ref]
    scene = os.path.basename(seq.rstrip("/"))
    d = f"runs/posterior/{scene}_{os.path.basename(wpath)}"
    os.makedirs(d, exist_ok=True)
    fr = features(f"{seq}/images/{frame}.png", wpath, f"{d}/{frame}.npy")
    cost = np.full((len(lives), xs.size, RHO.size), np.nan, np.float32)
    for i, n in enumerate(lives):
        f = features(f"{seq}/images/{n:05d}.png", wpath, f"{d}/{n:05d}.npy")
        u, v, front = project(k, poses[ref], np.linalg.inv(poses[n]), xs.astype(float), ys.astype(float), RHO)
        for s in range(0, xs.size, 1000):
            sl = slice(s, s + 1000)
            sample, inside = bilinear(f, u[sl], v[sl])
            e = np.abs(fr[ys[sl], xs[sl]][:, None, :] - sample).sum(-1)
            cost[i, sl] = np.where(inside & front[sl], e, np.nan)
    seen = ~np.isnan(cost)
    count = seen.sum(0)
    competing = count >= np.maximum(1, np.ceil(0.25 * count.max(1, keepdims=True)))
    zt = z[ys, xs]

    def wta_right(agg):
        agg = np.where(competing, agg, np.inf)
        depth = 1.0 / RHO[agg.argmin(1)]
        return np.maximum(depth / zt, zt / depth) < 1.25, agg

    def report(name, agg):
        right, _ = wta_right(agg)
        cells = [f"{c} {right[m[ys, xs]].mean():.3f}" for c, m in cats.items() if m[ys, xs].any()]
        print(f"{scene} {name:>8}: " + " | ".join(cells), flush=True)

    mean = np.nansum(cost, 0) / np.maximum(count, 1)
    report("mean", mean)
    ascending = np.cumsum(np.nan_to_num(np.sort(np.where(seen, cost, np.inf), axis=0), posinf=0.0), axis=0)
    for frac in (0.75, 0.5, 0.3):
        kk = np.maximum(1, np.ceil(frac * count)).astype(int)
        report(f"best{frac}", np.take_along_axis(ascending, (kk - 1)[None], 0)[0] / kk)
    report("median", np.nanmedian(cost, 0))

    right, agg = wta_right(mean)
    finite = np.where(np.isinf(agg), np.nan, agg)
    cmin = np.nanmin(finite, 1)
    ratio = cmin / np.nanmedian(finite, 1)
    for c, m in cats.items():
        sel = m[ys, xs]
        if sel.any():
            g, b = sel & right, sel & ~right
            med = lambda a, s: np.median(a[s]) if s.any() else float("nan")  # noqa: E731
            print(f"{c:>28}: right {g.sum():5d} min {med(cmin, g):.2f} min/median {med(ratio, g):.3f} | "
                  f"wrong {b.sum():5d} min {med(cmin, b):.2f} min/median {med(ratio, b):.3f}")
    print(f"AUC wrong > right: minimum {auc(cmin, ~right):.3f}, minimum/median {auc(ratio, ~right):.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
