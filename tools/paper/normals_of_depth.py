#!/usr/bin/env python3
"""Normals of a depth map by SPEC.md §10.2's `gt` rule (a plane fitted in inverse depth over the
(2r+1)² window, neighbours within 5 % of the pixel's depth, oriented towards the camera), written as a
`--normals DIR` file (`[H, W, 3]` '<f4', zero where there is none). A Python replica in f64 of
`mapping::depth_normals`, not its bits. Used in docs/table1/README.md ("Session 44") to feed the prior
the normals of the mapper's own learned-TV depth:

    python3 tools/paper/normals_of_depth.py DEPTH.npy K.txt DIR/NNNNN.npy [r]

`r` defaults to fit_radius's rule, max(1, round(3 min(|f_x|, |f_y|) / 256)).
"""
import sys

import numpy as np

depth = np.load(sys.argv[1]).astype(np.float64)
k = np.loadtxt(sys.argv[2])
out = sys.argv[3]
fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
r = int(sys.argv[4]) if len(sys.argv) > 4 else max(1, round(3 * min(abs(fx), abs(fy)) / 256))
h, w = depth.shape
valid = depth > 0
rho = np.where(valid, 1.0 / np.where(valid, depth, 1), 0)
# sums over the gated window: for each offset (dx, dy), neighbour included if valid and within 5 %
S = {key: np.zeros((h, w)) for key in ("n", "x", "y", "xx", "xy", "yy", "r", "rx", "ry")}
pad = lambda a, fill: np.pad(a, r, constant_values=fill)
dp, vp, rp = pad(depth, 0.0), pad(valid, False), pad(rho, 0.0)
for dy in range(-r, r + 1):
    for dx in range(-r, r + 1):
        dn = dp[r + dy:r + dy + h, r + dx:r + dx + w]
        vn = vp[r + dy:r + dy + h, r + dx:r + dx + w]
        rn = rp[r + dy:r + dy + h, r + dx:r + dx + w]
        m = (vn & valid & (np.abs(dn - depth) <= 0.05 * depth)).astype(np.float64)
        S["n"] += m; S["x"] += m * dx; S["y"] += m * dy
        S["xx"] += m * dx * dx; S["xy"] += m * dx * dy; S["yy"] += m * dy * dy
        S["r"] += m * rn; S["rx"] += m * rn * dx; S["ry"] += m * rn * dy
A = np.stack([np.stack([S["n"], S["x"], S["y"]], -1), np.stack([S["x"], S["xx"], S["xy"]], -1),
              np.stack([S["y"], S["xy"], S["yy"]], -1)], -2)
bvec = np.stack([S["r"], S["rx"], S["ry"]], -1)
det = np.linalg.det(A)
ok = valid & (S["n"] >= max(6, int(np.ceil((2 * r + 1) ** 2 / 4)))) & (np.abs(det) > 0.5)
sol = np.zeros((h, w, 3))
sol[ok] = np.linalg.solve(A[ok], bvec[ok][..., None])[..., 0]
a, b, c = sol[..., 0], sol[..., 1], sol[..., 2]
ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
n = np.stack([fx * b, fy * c, a + b * (cx - xs) + c * (cy - ys)], -1)
n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)
# orient towards the camera: n . X < 0, X = K^-1 u * z
ray = np.stack([(xs - cx) / fx, (ys - cy) / fy, np.ones_like(xs)], -1)
flip = (n * ray).sum(-1) > 0
n[flip] *= -1
n[~ok] = 0
np.save(out, n.astype("<f4"))
print(f"{out}: {ok.mean():.3f} with a normal, r {r}")
