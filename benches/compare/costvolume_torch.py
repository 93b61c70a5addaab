#!/usr/bin/env python3
"""Check and time densefeat's cost volume against an independent implementation (SPEC.md §9, §12.3).

One run:
  1. `densefeat bench costvolume --dump DIR` times our fast kernel (median ms per added frame on
     --threads threads) and writes the inputs (ref/live features, camera, T_nr, hypotheses), our
     one-frame volume, its counts and the error-budget magnitude M̄ of SPEC.md §9.6.
  2. This script rebuilds the same volume with PyTorch's grid_sample (mode="bilinear",
     align_corners=True, x_n = 2x/(W-1) - 1, SPEC.md §2.1; float32, batched over hypotheses) or, when
     torch cannot be imported, with numpy implementing the same sampling (float64 weights and sums).
     Samples behind the live camera (p_z <= 0) or outside [0, W-1] x [0, H-1] are masked out and
     counted, as in SPEC.md §9.1.
  3. It compares the counts (exactly) and the costs (max |ours - theirs| against the budget
     (C + N + 8) eps_f32 M̄, N = 1 frame) and prints both times and their ratio.

Usage (from the repository root, after `cargo build --release`):
  python3 benches/compare/costvolume_torch.py --threads 2            # torch if importable, else numpy
  python3 benches/compare/costvolume_torch.py --backend numpy --threads 2
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np


def load(dir_):
    meta = json.load(open(os.path.join(dir_, "meta.json")))
    arrays = {n: np.load(os.path.join(dir_, n + ".npy")) for n in ["ref", "live", "costs", "counts", "magnitude"]}
    return meta, arrays


def geometry(meta):
    """Per pixel a = R K^-1 u (f64, [H*W, 3]), t, and the hypotheses: SPEC.md §2.4's homogeneous warp."""
    w, h = meta["width"], meta["height"]
    m = np.array(meta["T_nr"], dtype=np.float64)
    r, t = m[:3, :3], m[:3, 3]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - meta["cx"]) / meta["fx"], (v - meta["cy"]) / meta["fy"], np.ones_like(u)], -1)
    a = rays.reshape(-1, 3) @ r.T
    return a, t, np.array(meta["rhos"], dtype=np.float64)


def project(meta, a, t, rho):
    """Warped positions (x, y) in pixels and the validity mask (in front, inside [0, W-1] x [0, H-1])."""
    w, h = meta["width"], meta["height"]
    p = a + rho * t
    with np.errstate(divide="ignore", invalid="ignore"):
        x = meta["fx"] * p[:, 0] / p[:, 2] + meta["cx"]
        y = meta["fy"] * p[:, 1] / p[:, 2] + meta["cy"]
    ok = (p[:, 2] > 0) & np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    return x, y, ok


def volume_numpy(meta, ref, live):
    """grid_sample(bilinear, align_corners=True) semantics on in-bounds samples, float64 sums."""
    h, w, c = ref.shape
    a, t, rhos = geometry(meta)
    live_flat = live.reshape(-1, c).astype(np.float64)
    ref_flat = ref.reshape(-1, c).astype(np.float64)
    costs = np.full((h * w, len(rhos)), np.nan)
    counts = np.zeros((h * w, len(rhos)), dtype=np.int64)
    for k, rho in enumerate(rhos):
        x, y, ok = project(meta, a, t, rho)
        idx = np.nonzero(ok)[0]
        # Normalise and unnormalise exactly as grid_sample(align_corners=True) does.
        xn, yn = 2 * x[idx] / (w - 1) - 1, 2 * y[idx] / (h - 1) - 1
        xs, ys = (xn + 1) / 2 * (w - 1), (yn + 1) / 2 * (h - 1)
        x0 = np.clip(np.floor(xs), 0, max(w - 2, 0)).astype(np.int64)
        y0 = np.clip(np.floor(ys), 0, max(h - 2, 0)).astype(np.int64)
        fa, fb = (xs - x0)[:, None], (ys - y0)[:, None]
        x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
        s = ((1 - fa) * (1 - fb) * live_flat[y0 * w + x0] + fa * (1 - fb) * live_flat[y0 * w + x1]
             + (1 - fa) * fb * live_flat[y1 * w + x0] + fa * fb * live_flat[y1 * w + x1])
        costs[idx, k] = np.abs(ref_flat[idx] - s.astype(np.float32)).sum(1)
        counts[idx, k] = 1
    return costs.reshape(h, w, -1), counts.reshape(h, w, -1)


def volume_torch(meta, ref, live, dtype, chunk=8):
    """torch.nn.functional.grid_sample over chunks of hypotheses (batch = hypotheses)."""
    import torch
    import torch.nn.functional as F

    h, w, c = ref.shape
    a, t, rhos = geometry(meta)
    live_t = torch.from_numpy(live).to(dtype).permute(2, 0, 1).unsqueeze(0)  # [1, C, H, W]
    ref_t = torch.from_numpy(ref).to(dtype).permute(2, 0, 1).unsqueeze(0)
    a_t, t_t = torch.from_numpy(a), torch.from_numpy(t)
    costs = torch.full((len(rhos), h, w), float("nan"), dtype=torch.float64)
    counts = torch.zeros((len(rhos), h, w), dtype=torch.int64)
    for k0 in range(0, len(rhos), chunk):
        rho = torch.from_numpy(rhos[k0:k0 + chunk])[:, None, None]  # [B, 1, 1]
        p = a_t[None] + rho * t_t[None, None]  # [B, H*W, 3], float64
        x = meta["fx"] * p[..., 0] / p[..., 2] + meta["cx"]
        y = meta["fy"] * p[..., 1] / p[..., 2] + meta["cy"]
        ok = (p[..., 2] > 0) & torch.isfinite(x) & torch.isfinite(y) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        grid = torch.stack([2 * x / (w - 1) - 1, 2 * y / (h - 1) - 1], -1).reshape(-1, h, w, 2)
        grid = torch.where(ok.reshape(-1, h, w, 1), grid, torch.zeros_like(grid)).to(dtype)
        b = grid.shape[0]
        s = F.grid_sample(live_t.expand(b, -1, -1, -1), grid, mode="bilinear", padding_mode="zeros", align_corners=True)
        e = (ref_t - s).abs().sum(1).to(torch.float64)  # [B, H, W]
        okr = ok.reshape(b, h, w)
        costs[k0:k0 + b] = torch.where(okr, e, costs[k0:k0 + b])
        counts[k0:k0 + b] = okr.to(torch.int64)
    return costs.permute(1, 2, 0).numpy(), counts.permute(1, 2, 0).numpy()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--binary", default="target/release/densefeat")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--bins", type=int, default=64)
    ap.add_argument("--channels", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=10, help="timed runs of each side")
    ap.add_argument("--backend", choices=["auto", "torch", "numpy"], default="auto")
    args = ap.parse_args()

    backend = args.backend
    if backend in ("auto", "torch"):
        try:
            import torch

            torch.set_num_threads(args.threads)
            backend = "torch"
        except Exception as e:  # noqa: BLE001 - any import failure means: no torch here
            if args.backend == "torch":
                sys.exit(f"torch cannot be imported: {e}")
            print(f"torch cannot be imported ({type(e).__name__}: {str(e)[:120]}); using numpy", file=sys.stderr)
            backend = "numpy"

    with tempfile.TemporaryDirectory() as d:
        cmd = [args.binary, "bench", "costvolume", "--size", args.size, "--bins", str(args.bins), "--channels",
               str(args.channels), "--threads", str(args.threads), "--runs", str(max(args.runs, 10)), "--dump", d]
        print("$", " ".join(cmd))
        print(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip())
        meta, arr = load(d)

    ref, live = arr["ref"], arr["live"]
    ours, our_counts = arr["costs"].astype(np.float64), arr["counts"].astype(np.int64)
    c = ref.shape[2]

    # Check (float64 for torch, so that the only differences are our f32 kernel's rounding).
    if backend == "torch":
        import torch

        theirs, counts = volume_torch(meta, ref, live, torch.float64)
    else:
        theirs, counts = volume_numpy(meta, ref, live)
    masked = int((counts == 0).sum())
    mismatched = int((counts != our_counts).sum())
    both = (counts > 0) & (our_counts > 0)
    diff = np.abs(ours[both] - theirs[both])
    budget = (c + 1 + 8) * np.finfo(np.float32).eps * arr["magnitude"].astype(np.float64)[both]
    worst = float((diff / budget).max())
    print(f"check ({backend}): {both.sum()} cells compared, {masked} of {counts.size} samples masked "
          f"(outside the image or behind the camera), {mismatched} count mismatches; "
          f"max |ours - {backend}| = {diff.max():.3e}, mean {diff.mean():.3e}; "
          f"max diff / SPEC §9.6 budget = {worst:.3f} ({'within' if worst <= 1 and mismatched == 0 else 'OUTSIDE'} budget)")

    # Timing: float32 for torch (what one would run), the float64 check path for numpy.
    times = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        if backend == "torch":
            volume_torch(meta, ref, live, torch.float32)
        else:
            volume_numpy(meta, ref, live)
        times.append(time.perf_counter() - t0)
    theirs_ms = 1e3 * float(np.median(times))
    ours_ms = meta["median_ms_per_frame"]
    print(f"time, {args.size}, K={args.bins}, C={c}, {args.threads} thread(s): densefeat ({meta['kernel']}) "
          f"{ours_ms:.1f} ms, {backend} {theirs_ms:.1f} ms (median of {args.runs}); "
          f"{backend} / densefeat = {theirs_ms / ours_ms:.1f}x")
    versions = {"python": sys.version.split()[0], "numpy": np.__version__}
    if backend == "torch":
        versions["torch"] = torch.__version__
    print("versions:", versions)
    return 0 if worst <= 1 and mismatched == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
