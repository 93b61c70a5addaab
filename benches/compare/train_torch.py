#!/usr/bin/env python3
"""One training step of densefeat re-implemented in PyTorch (CPU): same network, same loss.

Input: a folder written by `densefeat bench train --dump DIR` (SPEC.md §13.7): the pair
(`ref.npy`, `live.npy` [H, W, 3] 0-255, `depth.npy` [H, W, 1] metres), `weights.safetensors`,
our gradient `grads.safetensors` and `pair.json` (cameras, T_lr, loss settings, our per-scale
losses and pixel counts).

The step (SPEC §13.1-13.2): both images through the SPEC §8.3 module (`torch_network.build`: strict
state_dict load, input mean, bottom/right edge padding, crop of every map to its level's size), then
the loss at each block output L1..Ln and at the aggregated features L, each on its level l
(cameras f/2^l, c/2^l, ceil sizes; ground truth depth[2^l j, 2^l i]):
  E_k  = ||f_ref(u) - f_live(u'(rho_k))||^2   (grid_sample, bilinear, align_corners=True),
         outside_cost where u'(rho_k) is behind the live camera or outside [0, W'-1] x [0, H'-1]
  CE   = -log_softmax(-E)[l*] - sum_{l != l*} log(clamp(1 - P_l, prob_floor))
  loss = CE + lambda_rho (rho_hat - rho*)^2 + lambda_d (1/clamp(rho_hat, rho_floor) - 1/rho*)^2
mean over the used pixels (the mask and l* = round((rho* - rho_min) / step) as SPEC §13.1); the
objective is the sum of the scale means; autograd gives the weight gradients. The geometry (warp,
mask, sample positions) is computed in float64, inside the step, as ours does.

Checks: per-scale loss and pixel count (ours vs torch f32 vs torch f64), per-tensor gradient
max|a - b| / max|b| (ours vs torch f32, and both against torch f64). Exit status 1 if a pixel count
differs, a scale loss differs by more than 1e-4 relative, or a gradient by more than 1e-2.
Timing: median of --runs steps after one warm-up, torch.set_num_threads(--threads), PyTorch NCHW
and channels_last, beside `densefeat bench train` with the same crop, bins and threads.

Usage: python3 benches/compare/train_torch.py --dump DIR [--make-dump] [--crop 256x192]
       [--bins 256] [--b1-stride 2] [--threads 2] [--runs 5] [--densefeat PATH] [--skip-ours-timing]
       [--skip-timing] [--skip-f64]
"""
import argparse, copy, json, os, re, statistics, subprocess, sys, time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from torch_network import ROOT, build, read_safetensors

LOSS_TOL, GRAD_TOL = 1e-4, 1e-2


def load_dump(d):
    d = Path(d)
    pair = json.loads((d / "pair.json").read_text())
    img = lambda n: torch.from_numpy(np.load(d / n)).permute(2, 0, 1)[None].contiguous()  # NCHW
    return pair, img("ref.npy"), img("live.npy"), torch.from_numpy(np.load(d / "depth.npy")[:, :, 0])


def level_camera(cam, l):
    s = 0.5**l
    return dict(fx=cam["fx"] * s, fy=cam["fy"] * s, cx=cam["cx"] * s, cy=cam["cy"] * s,
                width=-(-cam["width"] // 2**l), height=-(-cam["height"] // 2**l))


def project(p0, rho, t, cam):
    """SPEC §2.4: p = R K_r^-1 u + rho t, u' = (fx px/pz + cx, fy py/pz + cy); also p_z > 0."""
    px, py, pz = (p0[i] + rho * t[i] for i in range(3))
    front = (pz > 0) & torch.isfinite(pz)
    return cam["fx"] * px / pz + cam["cx"], cam["fy"] * py / pz + cam["cy"], front


def inside(u, v, front, cam):
    return front & (u >= 0) & (v >= 0) & (u <= cam["width"] - 1) & (v <= cam["height"] - 1)


def geometry(pair, depth, level, rho):
    """Float64 warp of one level: used pixels (flat indices), targets, rho*, the grid_sample grid
    [N, K, 2] and which samples are defined [N, K]."""
    rc, lc = level_camera(pair["ref_camera"], level), level_camera(pair["live_camera"], level)
    T = torch.tensor(pair["T_lr"], dtype=torch.float64)
    k_inv = torch.tensor([[1 / rc["fx"], 0, -rc["cx"] / rc["fx"]], [0, 1 / rc["fy"], -rc["cy"] / rc["fy"]],
                          [0, 0, 1]], dtype=torch.float64)
    z = depth[:: 2**level, :: 2**level].double().reshape(-1)  # nearest on the level grid (§2.6)
    h, w = rc["height"], rc["width"]
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    p0 = (T[:3, :3] @ k_inv) @ torch.stack([xs.reshape(-1), ys.reshape(-1), torch.ones(h * w, dtype=torch.float64)])
    t = T[:3, 3]
    b = pair["bins"]
    valid = torch.isfinite(z) & (z > 0)
    rho_star = torch.where(valid, 1 / torch.where(valid, z, 1.0), -1.0)
    used = valid & (rho_star >= b["rho_min"]) & (rho_star <= b["rho_max"])
    u, v, front = project(p0, rho_star, t, lc)
    used &= inside(u, v, front, lc)
    idx = used.nonzero()[:, 0]
    rho_star = rho_star[idx]
    step = (b["rho_max"] - b["rho_min"]) / (b["count"] - 1)
    target = torch.floor((rho_star - b["rho_min"]) / step + 0.5).long().clamp(max=b["count"] - 1)
    u, v, front = project(p0[:, idx, None], rho[None, :], t, lc)  # [N, K]
    ok = inside(u, v, front, lc)
    wl, hl = lc["width"], lc["height"]
    grid = torch.stack([2 * u / max(wl - 1, 1) - 1, 2 * v / max(hl - 1, 1) - 1], -1)
    grid = torch.where(ok[..., None], grid, 0.0)  # no NaN/inf into grid_sample
    return idx, target, rho_star, grid, ok


def scale_loss(fr, fl, geo, rho, pair):
    """Mean loss of one scale; fr [C, H, W], fl [C, H', W'] (any dtype, autograd on both)."""
    idx, target, rho_star, grid, ok = geo
    if len(idx) == 0:
        return fr.sum() * 0
    dt = fr.dtype
    f_u = fr.reshape(fr.shape[0], -1)[:, idx]  # [C, N]
    s = F.grid_sample(fl[None], grid[None].to(dt), mode="bilinear", align_corners=True)[0]  # [C, N, K]
    e = ((f_u[:, :, None] - s) ** 2).sum(0)
    e = torch.where(ok, e, pair["outside_cost"])
    logp = torch.log_softmax(-e, 1)
    p = logp.exp()
    onehot = torch.zeros_like(ok).scatter_(1, target[:, None], True)
    ce = -logp.gather(1, target[:, None])[:, 0]
    ce = ce - torch.where(onehot, 0.0, torch.log(torch.clamp(1 - p, min=pair["prob_floor"]))).sum(1)
    rho = rho.to(dt)
    rho_hat = p @ rho
    d_hat = 1 / torch.clamp(rho_hat, min=pair["rho_floor"])
    rs = rho_star.to(dt)
    loss = ce + pair["lambda_rho"] * (rho_hat - rs) ** 2 + pair["lambda_d"] * (d_hat - 1 / rs) ** 2
    return loss.mean()


def forward(net, mean, s, imgs):
    """SPEC §8.1-8.2: mean, edge padding, the module; every block output and the aggregated
    features cropped to their levels. Returns ([(level, out_k)], (level, a_0)), NCHW."""
    n_blocks = len(net.blocks)
    h, w = imgs.shape[2:]
    m = 1 << (n_blocks - 1 + (1 if s == 2 else 0))
    x = F.pad(imgs - mean.to(imgs.dtype), (0, -(-w // m) * m - w, 0, -(-h // m) * m - h), mode="replicate")
    if net.blocks[0].conv1.weight.is_contiguous(memory_format=torch.channels_last):
        x = x.contiguous(memory_format=torch.channels_last)
    a, outs = net(x)
    lev = lambda k: k + (1 if s == 2 else 0)
    crop = lambda t, l: t[:, :, : -(-h // 2**l), : -(-w // 2**l)]
    return [(lev(k), crop(o, lev(k))) for k, o in enumerate(outs)], (lev(0), crop(a, lev(0)))


def train_step(net, mean, s, pair, ref, live, depth, rho):
    """Forward of both images (one batch of 2 when they have the same size), the six scale
    losses, backward. Returns [(loss, pixels)] in the order L1..Ln, L."""
    net.zero_grad(set_to_none=True)
    dt = net.blocks[0].conv1.weight.dtype
    if ref.shape == live.shape:
        blocks, agg = forward(net, mean, s, torch.cat([ref, live]).to(dt))
        pairs = [(l, o[0], o[1]) for l, o in blocks + [agg]]
    else:
        (br, ar), (bl, al) = forward(net, mean, s, ref.to(dt)), forward(net, mean, s, live.to(dt))
        pairs = [(l, o[0], q[0]) for (l, o), (_, q) in zip(br + [ar], bl + [al])]
    geos, losses = {}, []
    for level, fr, fl in pairs:
        if level not in geos:
            geos[level] = geometry(pair, depth, level, rho)
        losses.append((scale_loss(fr, fl, geos[level], rho, pair), len(geos[level][0])))
    sum(v for v, _ in losses).backward()
    return [(float(v.detach()), n) for v, n in losses]


def bins(pair):
    b = pair["bins"]
    rho = b["rho_min"] + torch.arange(b["count"], dtype=torch.float64) * (b["rho_max"] - b["rho_min"]) / (b["count"] - 1)
    rho[-1] = b["rho_max"]  # exact, as InverseDepthBins::rho
    return rho


def rel(a, b):
    return float((a.double() - b.double()).abs().max() / b.double().abs().max().clamp(min=1e-300))


def check(args, pair, ref, live, depth):
    net, mean, _, s = build(Path(args.dump) / "weights.safetensors")
    ours, _ = read_safetensors(Path(args.dump) / "grads.safetensors")
    rho = bins(pair)
    torch.set_num_threads(args.threads)
    res32 = train_step(net, mean, s, pair, ref, live, depth, rho)
    g32 = {n: p.grad.detach().clone() for n, p in net.named_parameters()}
    res64, g64 = None, None
    if not args.skip_f64:
        net64 = copy.deepcopy(net).double()
        res64 = train_step(net64, mean.double(), s, pair, ref, live, depth, rho)
        g64 = {n: p.grad.detach().clone() for n, p in net64.named_parameters()}
    names = [f"L{k + 1}" for k in range(len(pair["loss_blocks"]))] + ["L"]
    our_loss = pair["loss_blocks"] + [pair["loss_aggregated"]]
    our_pix = pair["pixels_blocks"] + [pair["pixels_aggregated"]]
    ok = True
    print("## Loss per scale: ours (pair.json) vs PyTorch\n")
    print("| scale | pixels ours | pixels torch | ours | torch f32 | rel ours-torch32 | torch f64 "
          "| rel ours-f64 | rel torch32-f64 |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = list(zip(names, our_pix, our_loss, res32, res64 or [(None, None)] * len(names)))
    rows.append(("total", sum(our_pix), pair["total"], (sum(v for v, _ in res32), sum(n for _, n in res32)),
                 (sum(v for v, _ in res64), None) if res64 else (None, None)))
    for name, pix, lo, (l32, n32), (l64, _) in rows:
        r = abs(lo - l32) / abs(l32)
        ok &= pix == n32 and r <= LOSS_TOL
        f64 = f"{l64:.9f} | {abs(lo - l64) / abs(l64):.2e} | {abs(l32 - l64) / abs(l64):.2e}" if l64 is not None else "— | — | —"
        print(f"| {name} | {pix} | {n32}{'' if pix == n32 else ' **MISMATCH**'} | {lo:.9f} | {l32:.9f} | {r:.2e} | {f64} |")
    print("\n## Gradient per tensor: max |a - b| / max |b|\n")
    print("| tensor | shape | max abs torch | ours vs torch32 | ours vs f64 | torch32 vs f64 |")
    print("|---|---|---|---|---|---|")
    assert set(ours) == set(g32), set(ours) ^ set(g32)
    worst = {"ours vs torch32": (0, ""), "ours vs f64": (0, ""), "torch32 vs f64": (0, "")}
    exact = g64 or g32
    top = max(float(g.abs().max()) for g in exact.values())
    closer, zero = 0, []
    for n, _ in net.named_parameters():
        if float(exact[n].abs().max()) < 1e-6 * top:
            # A gradient that is 0 in exact arithmetic (e.g. deconvs.0.bias: it shifts the L
            # features of both images alike, which no cost sees): relative error is meaningless;
            # give max |a - b| / (max over all tensors of |grad|) instead.
            zero.append(n)
            ab = lambda a, b: float((a.double() - b.double()).abs().max()) / top
            cols = {"ours vs torch32": ab(ours[n], g32[n])}
            if g64:
                cols["ours vs f64"], cols["torch32 vs f64"] = ab(ours[n], g64[n]), ab(g32[n], g64[n])
            cells = " | ".join(f"{cols[c]:.2e}*" if c in cols else "—" for c in worst)
        else:
            cols = {"ours vs torch32": rel(ours[n], g32[n])}
            if g64:
                cols["ours vs f64"], cols["torch32 vs f64"] = rel(ours[n], g64[n]), rel(g32[n], g64[n])
                closer += cols["ours vs f64"] < cols["torch32 vs f64"]
            for c, v in cols.items():
                worst[c] = max(worst[c], (v, n))
            cells = " | ".join(f"{cols[c]:.2e}" if c in cols else "—" for c in worst)
        print(f"| {n} | {list(g32[n].shape)} | {float(g32[n].abs().max()):.3e} | {cells} |")
    if zero:
        print(f"\n\\* exact gradient 0 ({', '.join(zero)}: max |f64| < 1e-6 of the largest entry): "
              f"max |a - b| / {top:.3e} (the largest gradient entry of any tensor); not in `worst`.")
    print("\nworst: " + "; ".join(f"{c} {v:.2e} ({n})" for c, (v, n) in worst.items() if n))
    if g64:
        print(f"ours is closer to f64 than torch f32 is for {closer} of {len(ours) - len(zero)} tensors")
    ok &= worst["ours vs torch32"][0] <= GRAD_TOL
    flat = lambda g: torch.cat([g[n].reshape(-1).double() for n, _ in net.named_parameters()])
    print(f"whole gradient (all tensors as one vector): ours vs torch32 {rel(flat(ours), flat(g32)):.2e}"
          + (f", ours vs f64 {rel(flat(ours), flat(g64)):.2e}, torch32 vs f64 {rel(flat(g32), flat(g64)):.2e}" if g64 else ""))
    return ok, net, mean, s, rho


def median_ms(fn, runs):
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def time_torch(net, mean, s, pair, ref, live, depth, rho, args):
    torch.set_num_threads(args.threads)
    out = {}
    for layout in ("NCHW", "channels_last"):
        n = copy.deepcopy(net)
        if layout == "channels_last":
            n = n.to(memory_format=torch.channels_last)
        out[layout] = median_ms(lambda: train_step(n, mean, s, pair, ref, live, depth, rho), args.runs)
        with torch.no_grad():
            out[layout + " fwd"] = median_ms(lambda: forward(n, mean, s, torch.cat([ref, live])), args.runs)
    return out


def run_ours(args, extra):
    cmd = [args.densefeat, "bench", "train", "--crop", args.crop, "--bins", str(args.bins),
           "--threads", str(args.threads), "--b1-stride", str(args.b1_stride)] + extra
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stderr}")
    return r.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dump", required=True, help="folder of `densefeat bench train --dump`")
    ap.add_argument("--make-dump", action="store_true", help="run `densefeat bench train --dump` first")
    ap.add_argument("--crop", help="WxH for --make-dump and our timing (default: the dump's, else 256x192)")
    ap.add_argument("--bins", type=int, help="bins for --make-dump (default: the dump's, else 256)")
    ap.add_argument("--b1-stride", type=int, default=2, help="for --make-dump (default 2)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--densefeat", default=os.environ.get("CARGO_TARGET_DIR", str(ROOT / "target")) + "/release/densefeat")
    ap.add_argument("--skip-ours-timing", action="store_true")
    ap.add_argument("--skip-timing", action="store_true", help="no timing at all")
    ap.add_argument("--skip-f64", action="store_true", help="no float64 reference run")
    args = ap.parse_args()
    if args.make_dump:
        args.crop, args.bins = args.crop or "256x192", args.bins or 256
        print(run_ours(args, ["--runs", "1", "--dump", args.dump]).splitlines()[0])
    pair, ref, live, depth = load_dump(args.dump)
    _, meta = read_safetensors(Path(args.dump) / "weights.safetensors")
    args.b1_stride = int(meta["b1_stride"])
    args.crop = args.crop or f"{pair['ref_camera']['width']}x{pair['ref_camera']['height']}"
    args.bins = args.bins or pair["bins"]["count"]
    print(f"torch {torch.__version__}, numpy {np.__version__}, cpus {os.cpu_count()}, load {os.getloadavg()}")
    print(f"dump {args.dump}: crop {args.crop}, {args.bins} bins, b1 stride {args.b1_stride}, "
          f"blocks {meta['blocks']}, channels {meta['channels']}\n")
    ok, net, mean, s, rho = check(args, pair, ref, live, depth)
    if not args.skip_timing:
        print(f"\n## Timing: one step (forward both images + loss at {len(net.blocks) + 1} scales + backward), "
              f"median of {args.runs} after 1 warm-up, {args.threads} threads\n")
        t = time_torch(net, mean, s, pair, ref, live, depth, rho, args)
        for layout in ("NCHW", "channels_last"):
            print(f"torch {layout}: step {t[layout]:.1f} ms, forward of both images (no_grad) {t[layout + ' fwd']:.1f} ms")
        if not args.skip_ours_timing:
            out = run_ours(args, ["--runs", str(args.runs)])
            step = float(re.search(r"one pair .*?: ([\d.]+) ms median", out).group(1))
            fwd = float(re.search(r"network forward of both images: ([\d.]+) ms", out).group(1))
            best = min(t["NCHW"], t["channels_last"])
            print(f"densefeat: step {step:.1f} ms, forward of both images {fwd:.1f} ms")
            print(f"densefeat / best torch (step): {step / best:.2f}   (load {os.getloadavg()[0]:.1f})")
    print("\ncorrectness:", "pixel counts equal, losses and gradients within tolerance" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
