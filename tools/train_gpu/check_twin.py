#!/usr/bin/env python3
"""Check that train_gpu.py's batched loss equals benches/compare/train_torch.py's per-pair loss
(itself checked equal to densefeat's, SPEC §13.7) on a batch of real training pairs, in float64.

Usage: python3 tools/train_gpu/check_twin.py --init W --pack DIR [--synth DIR] [--batch 3]
Exit status 1 if any pair's scale loss differs by more than 1e-9 relative or a pixel count differs.
"""
import argparse, sys
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1] / "benches" / "compare"))
import train_gpu as G  # noqa: E402
import train_torch as T  # noqa: E402
from torch_network import build  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--init", required=True)
    ap.add_argument("--pack", nargs="*", default=[])
    ap.add_argument("--synth", nargs="*", default=[])
    ap.add_argument("--batch", type=int, default=3)
    ap.add_argument("--crop", default="96x64")
    ap.add_argument("--bins", type=int, default=48)
    a = ap.parse_args()
    dev = torch.device("cpu")
    cw, ch = map(int, a.crop.split("x"))
    rule = dict(min_baseline=0.05, max_baseline=0.5, max_rot=30.0, min_overlap=0.6)
    cfg = dict(bins=a.bins, rho_min=0.0, rho_max=4.0, outside_cost=10.0, prob_floor=1e-6, rho_floor=0.1,
               lambda_rho=5.0, lambda_d=1.0)
    scenes = [G.load_pack(d, dev) for d in a.pack] + [G.load_dvmvs(d, dev) for d in a.synth]
    pairs = [G.pair_list(sc, rule) for sc in scenes]
    gen = torch.Generator().manual_seed(1)
    w = torch.ones(len(scenes), dtype=torch.float64)
    ref, live, depth, cr, cl, Tlr = G.make_batch(scenes, pairs, w, a.batch, (cw, ch), gen, True)
    net, mean, _, s = build(a.init)
    net = net.double()
    rho = G.bins_rho(cfg, dev)
    outs = G.forward(net, mean.double(), s, torch.cat([ref, live]).double())
    ok = True
    for level, f in outs:
        hw = f.shape[2:]
        geo = G.geometry(depth, cr, cl, Tlr, level, rho, cfg, hw)
        pp, n, _ = G.scale_loss(f[: a.batch], f[a.batch:], geo, rho.double(), cfg)
        for b in range(a.batch):
            cam = lambda c: dict(fx=float(c[0]), fy=float(c[1]), cx=float(c[2]), cy=float(c[3]), width=cw, height=ch)
            pair = dict(ref_camera=cam(cr[b]), live_camera=cam(cl[b]), T_lr=Tlr[b].tolist(),
                        bins=dict(rho_min=0.0, rho_max=4.0, count=a.bins), **{k: cfg[k] for k in
                        ("outside_cost", "prob_floor", "rho_floor", "lambda_rho", "lambda_d")})
            g = T.geometry(pair, depth[b], level, rho)
            ref_loss = float(T.scale_loss(f[b], f[a.batch + b], g, rho, pair).detach())
            mine = float(pp[b])
            rel = abs(mine - ref_loss) / max(abs(ref_loss), 1e-300)
            same_n = int(n[b]) == len(g[0])
            ok &= same_n and rel <= 1e-9
            print(f"level {level} pair {b}: pixels {int(n[b])} vs {len(g[0])}, loss {mine:.12f} vs {ref_loss:.12f} (rel {rel:.1e})")
    print("equal" if ok else "DIFFERENT")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
