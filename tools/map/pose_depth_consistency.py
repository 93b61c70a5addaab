#!/usr/bin/env python3
"""Do a sequence's poses agree with its depth? (issue 31: what limits a mesh judged at 5 cm)

For keyframes k (every STEP frames) and live frames k +- 10, k +- 20, the keyframe's ground-truth
depth is warped into the live frame with the given relative pose, and that pose is then refined
by direct image alignment (6 degrees of freedom, Gauss-Newton on the grey-level error of
high-gradient pixels, Huber-like weights, a gain and offset of the live frame refitted at each
step, 2 pyramid levels). With consistent data the refinement
moves nothing; with poses that disagree with the depth it moves the pose, and the ratio
|t_refined| / |t_given| is the factor by which the images' own geometry says the depth should be
scaled (an image-based method using the given poses triangulates depth that much off the sensor's).

    tools/map/pose_depth_consistency.py [--step N] [--depth-scale S] [--plot OUT.png] SEQ...

SEQ: a folder with K.txt, poses.txt (camera-to-world 4x4 per line), images/, depth/ (uint16 PNG in
millimetres unless --depth-scale says otherwise; keyframes every --step frames, default 5). Needs
numpy and Pillow (and matplotlib for --plot: the translation ratio of every pair, per sequence).
Prints one line per pair and per sequence a summary (median translation ratio, its quartiles, the fraction of pairs within 2.5 %
and 10 % of 1, mean rotation correction, mean grey error before / after).
"""
import functools
import os
import sys

import numpy as np
from PIL import Image


def bilinear(img, x, y):
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def blur(img):
    k = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
    img = np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 0, img)
    return np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 1, img)


def half(img):
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    return img[:h, :w].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))


def grads(img):
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = (img[:, 2:] - img[:, :-2]) / 2
    gy[1:-1] = (img[2:] - img[:-2]) / 2
    return gx, gy


def so3_exp(w):
    th = np.linalg.norm(w)
    a = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-12:
        return np.eye(3) + a
    return np.eye(3) + np.sin(th) / th * a + (1 - np.cos(th)) / th**2 * a @ a


def project(k, t, pts, shape):
    q = k @ (t[:3, :3] @ pts + t[:3, 3:4])
    x, y = q[0] / q[2], q[1] / q[2]
    h, w = shape
    ok = (x >= 1) & (x < w - 2) & (y >= 1) & (y < h - 2) & (q[2] > 0)
    return x, y, ok


def grey_error(k, t, pts, ref, live):
    x, y, ok = project(k, t, pts, live.shape)
    if ok.sum() < 100:
        return float("nan")
    val = bilinear(live, x[ok], y[ok])
    gain, offset = np.polyfit(val, ref[ok], 1)
    return float(np.mean(np.abs(gain * val + offset - ref[ok])))


def align(k, t, pts, ref, live, iters=15):
    gx, gy = grads(live)
    for _ in range(iters):
        x, y, ok = project(k, t, pts, live.shape)
        if ok.sum() < 100:
            break
        p = t[:3, :3] @ pts[:, ok] + t[:3, 3:4]
        z = p[2]
        ix, iy = bilinear(gx, x[ok], y[ok]), bilinear(gy, x[ok], y[ok])
        val = bilinear(live, x[ok], y[ok])
        # Gain and offset of the live frame against the keyframe, refitted every step (exposure).
        gain, offset = np.polyfit(val, ref[ok], 1)
        r = gain * val + offset - ref[ok]
        ix, iy = gain * ix, gain * iy
        di = np.stack([ix * k[0, 0] / z, iy * k[1, 1] / z,
                       -(ix * k[0, 0] * p[0] + iy * k[1, 1] * p[1]) / z**2])
        jw = np.cross(p.T, di.T).T  # d r / d w for p -> exp(w) p
        j = np.vstack([jw, di]).T
        wt = 1.0 / np.maximum(np.abs(r), 5.0)
        a = (j * wt[:, None]).T @ j + 1e-6 * np.eye(6)
        d = -np.linalg.solve(a, (j * wt[:, None]).T @ r)
        rot = so3_exp(d[:3])
        t = np.vstack([np.hstack([rot @ t[:3, :3], rot @ t[:3, 3:4] + d[3:, None]]), [0, 0, 0, 1]])
    return t


def load_sequence(seq):
    """K (3x3), the camera-to-world poses, and the sorted image and depth file names of SEQ."""
    v = [float(x) for x in open(os.path.join(seq, "K.txt")).read().split()]
    k0 = np.array(v[:9]).reshape(3, 3) if len(v) >= 9 else np.array(
        [[v[0], 0, v[2]], [0, v[1], v[3]], [0, 0, 1]])
    poses = np.loadtxt(os.path.join(seq, "poses.txt")).reshape(-1, 4, 4)
    names = sorted(os.listdir(os.path.join(seq, "images")))
    dnames = sorted(os.listdir(os.path.join(seq, "depth")))
    return k0, poses, names, dnames


def pairs(poses, step, offsets):
    """(keyframe, live frame, keyframe -> live pose) for keyframes every `step` frames and live frames
    at `offsets` from them, inside the sequence and at least 2 cm apart."""
    n = len(poses)
    for kf in range(0, n, step):
        for off in offsets:
            j = kf + off
            if not 0 <= j < n:
                continue
            t0 = np.linalg.inv(poses[j]) @ poses[kf]
            if np.linalg.norm(t0[:3, 3]) >= 0.02:
                yield kf, j, t0


def usable(ref, dep):
    """The keyframe pixels the alignment uses: with depth, a grey gradient over 2 levels, 2 px inside."""
    gx, gy = grads(ref)
    m = (dep > 0) & (np.hypot(gx, gy) > 2.0)
    m[:2], m[-2:], m[:, :2], m[:, -2:] = False, False, False, False
    return m


def refine_pair(k0, depth, ref0, live0, t0, min_points=0):
    """The keyframe -> live pose `t0` refined by direct alignment against the keyframe's depth,
    coarse to fine (level 1 at half resolution, then level 0), and the grey error at full resolution
    with the given and with the refined pose: (t, e0, e1). None when a level has fewer than
    `min_points` usable pixels."""
    t = t0.copy()
    for lvl in (1, 0):
        ref, live, dep, kk = ref0, live0, depth, k0.copy()
        if lvl == 1:
            ref, live = half(ref0), half(live0)
            dep = depth[: depth.shape[0] // 2 * 2: 2, : depth.shape[1] // 2 * 2: 2]
            kk[:2] /= 2
            kk[0, 2] = (k0[0, 2] + 0.5) / 2 - 0.5
            kk[1, 2] = (k0[1, 2] + 0.5) / 2 - 0.5
        yy, xx = np.mgrid[0: ref.shape[0], 0: ref.shape[1]]
        m = usable(ref, dep)
        if m.sum() < min_points:
            return None
        pts = np.linalg.inv(kk) @ np.stack([xx[m], yy[m], np.ones(m.sum())]) * dep[m]
        t = align(kk, t, pts, ref[m], live)
    return t, grey_error(kk, t0, pts, ref[m], live), grey_error(kk, t, pts, ref[m], live)


def check(seq, step, dscale, offsets=(-20, -10, 10, 20)):
    k0, poses, names, dnames = load_sequence(seq)

    @functools.lru_cache(maxsize=None)
    def blurred_grey(i):
        # Each frame is a keyframe once and a live frame of up to four pairs: decode it once.
        img = np.array(Image.open(os.path.join(seq, "images", names[i])).convert("L"), dtype=float)
        return blur(img)

    @functools.lru_cache(maxsize=1)
    def depth_of(kf):
        return np.array(Image.open(os.path.join(seq, "depth", dnames[kf])), dtype=float) / dscale

    rows = []
    for kf, j, t0 in pairs(poses, step, offsets):
        t, e0, e1 = refine_pair(k0, depth_of(kf), blurred_grey(kf), blurred_grey(j), t0)
        dt = t @ np.linalg.inv(t0)
        ang = np.degrees(np.arccos(np.clip((np.trace(dt[:3, :3]) - 1) / 2, -1, 1)))
        ratio = np.linalg.norm(t[:3, 3]) / np.linalg.norm(t0[:3, 3])
        rows.append((kf, j, ratio, ang, e0, e1))
        print(f"key {kf:3d} live {j:3d}: |t| {100 * np.linalg.norm(t0[:3, 3]):5.1f} cm, "
              f"translation ratio {ratio:.3f}, rotation corrected {ang:.2f} deg, "
              f"grey error {e0:.1f} -> {e1:.1f}")
    r = np.array([x[2] for x in rows])
    print(f"{seq}: {len(rows)} pairs; translation ratio median {np.median(r):.3f} "
          f"(quartiles {np.percentile(r, 25):.3f} - {np.percentile(r, 75):.3f}); "
          f"within 2.5 % of 1: {np.mean(np.abs(r - 1) < 0.025):.2f}, within 10 %: "
          f"{np.mean(np.abs(r - 1) < 0.1):.2f}; rotation corrected {np.mean([x[3] for x in rows]):.2f} deg "
          f"on average; grey error {np.nanmean([x[4] for x in rows]):.1f} -> {np.nanmean([x[5] for x in rows]):.1f}")
    return r


def main():
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seqs", nargs="+")
    ap.add_argument("--step", type=int, default=5)
    ap.add_argument("--offsets", default="-20,-10,10,20",
                    help="live frames relative to each keyframe (the trainer's pairs are 5-50 cm apart)")
    ap.add_argument("--depth-scale", type=float, default=1000.0)
    ap.add_argument("--plot")
    a = ap.parse_args()
    ratios = {os.path.basename(os.path.normpath(s)): check(s, a.step, a.depth_scale, [int(o) for o in a.offsets.split(",")]) for s in a.seqs}
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(8, 0.6 * len(ratios) + 1.5))
        for i, (name, r) in enumerate(ratios.items()):
            ax.scatter(r, np.full(len(r), i) + np.linspace(-0.15, 0.15, len(r)), s=12, zorder=3)
        ax.axvspan(0.975, 1.025, color="0.85", zorder=0, label="within 2.5 % (5 cm at 2 m)")
        ax.axvline(1.0, color="k", lw=0.8, zorder=1)
        ax.set_yticks(range(len(ratios)), list(ratios))
        ax.set_xlabel("|t| after direct alignment with the ground-truth depth / |t| given")
        ax.set_title("Do the poses agree with the depth? (1 = yes)")
        ax.legend(loc="lower right", fontsize=8)
        fig.tight_layout()
        fig.savefig(a.plot, dpi=110)


if __name__ == "__main__":
    main()
