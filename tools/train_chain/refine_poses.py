#!/usr/bin/env python3
"""A copy of a posed RGB-D sequence whose poses agree with its own depth (a training-data lever,
docs/training/README.md: the real training pairs' poses are about 2 px off their depth).

Each frame i is aligned to frames i + d for d in --edges (default 1,2) by the direct alignment of
tools/map/pose_depth_consistency.py: frame i's ground-truth depth warped into frame j, 6 degrees of
freedom, gain and offset, two pyramid levels. Those relative poses are the edges of a pose graph
whose unknowns are one correction per frame (P_i <- P_i exp(delta_i)); a weak prior keeps every
correction near zero, so a frame without edges keeps its pose and the graph has no free gauge.
Gauss-Newton with finite-difference Jacobians, three rounds. Rotation residuals are in radians,
translation residuals in metres times --trans-weight (default 0.5: 1 m of baseline error at 2 m is
about half a radian of ray direction).

    tools/train_chain/refine_poses.py SEQ OUT [--edges 1,2] [--depth-scale 1000]

OUT gets poses.txt (refined, camera-to-world, one 4x4 per line as in SEQ) and a symbolic link to
every other entry of SEQ. Check it on other pair spacings than the edges, e.g.
`tools/map/pose_depth_consistency.py --offsets=-3,3 SEQ OUT`. Needs numpy and Pillow.
"""
import argparse
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "map"))
from pose_depth_consistency import blur, load_sequence, refine_pair, so3_exp  # noqa: E402


def so3_log(r):
    c = np.clip((np.trace(r) - 1) / 2, -1.0, 1.0)
    th = np.arccos(c)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if th < 1e-9:
        return w / 2
    return w * th / (2 * np.sin(th))


def exp6(d):
    t = np.eye(4)
    t[:3, :3] = so3_exp(d[:3])
    t[:3, 3] = d[3:]
    return t


def log6(t):
    return np.concatenate([so3_log(t[:3, :3]), t[:3, 3]])


def measure(seq, loaded, edges, dscale):
    """Relative poses camera i -> camera j refined against frame i's depth, for j = i + d
    (`loaded`: what `load_sequence` read of SEQ)."""
    k0, poses, names, dnames = loaded
    n = len(poses)
    grey = {}

    def g(i):
        if i not in grey:
            img = np.array(Image.open(os.path.join(seq, "images", names[i])).convert("L"), dtype=float)
            grey[i] = blur(img)
        return grey[i]

    out = []
    for i in range(n):
        depth = np.array(Image.open(os.path.join(seq, "depth", dnames[i])), dtype=float) / dscale
        for d in edges:
            j = i + d
            if j >= n:
                continue
            r = refine_pair(k0, depth, g(i), g(j), np.linalg.inv(poses[j]) @ poses[i], min_points=200)
            # An alignment that did not lower the error (occlusion, blur, too little overlap) is
            # no measurement.
            if r is not None and np.isfinite(r[1]) and np.isfinite(r[2]) and r[2] < r[1]:
                out.append((i, j, r[0]))
        grey.pop(i - max(edges), None)
    return out


def residual(p_i, p_j, z, wt):
    r = log6(np.linalg.inv(z) @ np.linalg.inv(p_j) @ p_i)
    r[3:] *= wt
    return r


def refine(poses, meas, trans_weight, prior=1e-2, rounds=3, h=1e-6):
    n = len(poses)
    p = poses.copy()
    for _ in range(rounds):
        rows, rhs = [], []
        a = prior * np.eye(6 * n)
        b = np.zeros(6 * n)
        for i, j, z in meas:
            r0 = residual(p[i], p[j], z, trans_weight)
            jac = np.zeros((6, 12))
            for c in range(12):
                d = np.zeros(6)
                d[c % 6] = h
                if c < 6:
                    r = residual(p[i] @ exp6(d), p[j], z, trans_weight)
                else:
                    r = residual(p[i], p[j] @ exp6(d), z, trans_weight)
                jac[:, c] = (r - r0) / h
            idx = np.r_[6 * i: 6 * i + 6, 6 * j: 6 * j + 6]
            a[np.ix_(idx, idx)] += jac.T @ jac
            b[idx] -= jac.T @ r0
        delta = np.linalg.solve(a, b)
        p = np.array([p[i] @ exp6(delta[6 * i: 6 * i + 6]) for i in range(n)])
    return p


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seq")
    ap.add_argument("out")
    ap.add_argument("--edges", default="1,2")
    ap.add_argument("--depth-scale", type=float, default=1000.0)
    ap.add_argument("--trans-weight", type=float, default=0.5)
    a = ap.parse_args()
    edges = [int(e) for e in a.edges.split(",")]
    loaded = load_sequence(a.seq)
    poses = loaded[1]
    meas = measure(a.seq, loaded, edges, a.depth_scale)
    before = np.array([np.linalg.norm(residual(poses[i], poses[j], z, a.trans_weight)) for i, j, z in meas])
    refined = refine(poses, meas, a.trans_weight)
    after = np.array([np.linalg.norm(residual(refined[i], refined[j], z, a.trans_weight)) for i, j, z in meas])
    moved = [np.degrees(np.linalg.norm(so3_log(poses[i][:3, :3].T @ refined[i][:3, :3]))) for i in range(len(poses))]
    print(f"{a.seq}: {len(meas)} edges kept of {sum(1 for i in range(len(poses)) for d in edges if i + d < len(poses))}; "
          f"edge residual (rad, trans-weighted m) median {np.median(before):.4f} -> {np.median(after):.4f}; "
          f"frames turned by {np.mean(moved):.2f} deg on average (max {np.max(moved):.2f})")
    os.makedirs(a.out, exist_ok=True)
    for entry in os.listdir(a.seq):
        if entry == "poses.txt":
            continue
        dst = os.path.join(a.out, entry)
        if not os.path.lexists(dst):
            os.symlink(os.path.abspath(os.path.join(a.seq, entry)), dst)
    np.savetxt(os.path.join(a.out, "poses.txt"), refined.reshape(len(refined), 16), fmt="%.9e")


if __name__ == "__main__":
    main()
