#!/usr/bin/env python3
"""Train densefeat's feature network on a GPU with the PyTorch twin of our loss (SPEC.md §13.9).

The network is the SPEC §8.3 module (`benches/compare/torch_network.build`, strict state_dict
load); the loss at each scale is SPEC §13.1 exactly as `benches/compare/train_torch.py` computes it
(checked equal to ours there), batched over pairs: per pair and scale the mean over that pair's
used pixels, per pair the sum over the six scales L1..L5, L, and the batch objective is the mean
over pairs (as `densefeat train`). The optimiser is ours (§13.4): AdamW, linear warm-up then cosine
to `lr_final_fraction`, weight decay on conv/deconv weights only, global-norm clipping at
`--clip` (a safety net: the log counts how often it fired).

Data (SPEC §13.9): training scenes only (SPEC §3a): packed real sequences (`pack.py`) and
rendered DeepVideoMVS folders. Pairs follow SPEC §13.5's rule (baseline, rotation, overlap), crops
and augmentation as §13.5; pair scene chosen by `--mix` weights.

Outputs in --out: `log.csv` (one row per step), `snap_XXXXXX.safetensors` (weights in the §8.4
format at every --snap-every steps and at the end), `final_checkpoint.safetensors` (weights +
Adam moments `adam.m.*`/`adam.v.*`, metadata step/adam_step: resumable with --resume), `curves.png`.

Usage: python3 tools/train_gpu/train_gpu.py --init W.safetensors --pack DIR [DIR ...]
       [--synth DIR ...] --out DIR [--budget-s 420 | --steps N] [--batch 16] [--crop 256x192] ...
"""
import argparse, csv, json, math, os, struct, sys, time, zlib
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benches" / "compare"))
import train_torch  # noqa: E402
from torch_network import build, read_safetensors  # noqa: E402

# ---------------------------------------------------------------- data


def load_pack(d, dev):
    d = Path(d)
    m = json.loads((d / "meta.json").read_text())
    from PIL import Image

    rgb = np.stack([np.asarray(Image.open(d / f"{n}.jpg").convert("RGB")) for n in m["frames"]])
    raw = np.frombuffer(zlib.decompress((d / "depth.u16.z").read_bytes()), dtype="<u2")
    depth = raw.reshape(len(m["frames"]), m["height"], m["width"]).astype(np.float32) * 1e-3
    poses = np.array(m["poses"], dtype=np.float64)
    return scene(m["name"], rgb, depth, poses, (m["fx"], m["fy"], m["cx"], m["cy"]), dev)


def load_dvmvs(d, dev):
    """A DeepVideoMVS folder (what `densefeat synth` writes)."""
    from PIL import Image

    d = Path(d)
    ims = sorted(p for p in (d / "images").iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    rgb = np.stack([np.asarray(Image.open(p).convert("RGB")) for p in ims])
    depth = np.stack([np.asarray(Image.open(d / "depth" / f"{p.stem}.png")).astype(np.float32) * 1e-3 for p in ims])
    depth[depth >= 65.535] = 0
    poses = np.array([list(map(float, l.split())) for l in (d / "poses.txt").read_text().splitlines() if l.strip()])
    poses = poses.reshape(-1, 4, 4)
    k = [list(map(float, l.split())) for l in (d / "K.txt").read_text().splitlines() if l.strip()]
    return scene(d.name, rgb, depth, poses, (k[0][0], k[1][1], k[0][2], k[1][2]), dev)


def scene(name, rgb, depth, poses, k, dev):
    return dict(name=name, rgb=torch.from_numpy(rgb).to(dev), depth=torch.from_numpy(depth).to(dev),
                poses=torch.from_numpy(poses).to(dev), k=k, h=rgb.shape[1], w=rgb.shape[2])


def project_grid(sc, i, js, stride=4):
    """Overlap of frame i's valid-depth pixels (every `stride` px) in frames js, and mean flow."""
    z = sc["depth"][i, ::stride, ::stride].double()
    fx, fy, cx, cy = sc["k"]
    ys, xs = torch.meshgrid(torch.arange(0, sc["h"], stride, device=z.device, dtype=torch.float64),
                            torch.arange(0, sc["w"], stride, device=z.device, dtype=torch.float64), indexing="ij")
    ok = z > 0
    x, y, zz = xs[ok], ys[ok], z[ok]
    pc = torch.stack([(x - cx) / fx * zz, (y - cy) / fy * zz, zz, torch.ones_like(zz)])  # [4, P]
    T = torch.linalg.inv(sc["poses"][js]) @ sc["poses"][i]  # [J, 4, 4] ref -> live
    q = T @ pc  # [J, 4, P]
    front = q[:, 2] > 1e-6
    u = fx * q[:, 0] / q[:, 2] + cx
    v = fy * q[:, 1] / q[:, 2] + cy
    ins = front & (u >= 0) & (v >= 0) & (u <= sc["w"] - 1) & (v <= sc["h"] - 1)
    n = max(int(ok.sum()), 1)
    return ins.sum(1).double() / n


def pair_list(sc, rule):
    """SPEC §13.5: baseline in [min, max], relative rotation <= max_rot, overlap >= min_overlap."""
    P = sc["poses"]
    c = P[:, :3, 3]
    dist = torch.cdist(c, c)
    R = P[:, :3, :3]
    rel = torch.einsum("iab,jac->ijbc", R, R)  # R_i^T R_j
    tr = rel.diagonal(dim1=-2, dim2=-1).sum(-1)
    ang = torch.rad2deg(torch.arccos(((tr - 1) / 2).clamp(-1, 1)))
    cand = (dist >= rule["min_baseline"]) & (dist <= rule["max_baseline"]) & (ang <= rule["max_rot"])
    pairs = []
    for i in range(len(P)):
        js = cand[i].nonzero()[:, 0]
        if len(js) == 0:
            continue
        ov = project_grid(sc, i, js)
        for j in js[ov >= rule["min_overlap"]].tolist():
            pairs.append((i, j))
    return pairs


def gather_crop(img, idx, y0, x0, ch, cw):
    """img [F, H, W, ...]; crops [B, ch, cw, ...] at per-item offsets."""
    dev = img.device
    ys = y0[:, None] + torch.arange(ch, device=dev)[None]
    xs = x0[:, None] + torch.arange(cw, device=dev)[None]
    return img[idx[:, None, None], ys[:, :, None], xs[:, None, :]]


def make_batch(scenes, pairs, weights, B, crop, gen, aug):
    """B pairs (scene by weight, pair uniform), crops (live follows the mean flow), augmentation.
    Returns ref, live [B,3,ch,cw] float 0-255, depth [B,ch,cw], cams (ref, live) [B,4], T_lr [B,4,4]."""
    cw, ch = crop
    dev = scenes[0]["rgb"].device
    which = torch.multinomial(weights, B, replacement=True, generator=gen).tolist()
    out = []
    for s in sorted(set(which)):
        sc, pl = scenes[s], pairs[s]
        g = which.count(s)
        pick = torch.randint(len(pl), (g,), generator=gen).tolist()
        a = torch.tensor([pl[p][0] for p in pick], device=dev)
        b = torch.tensor([pl[p][1] for p in pick], device=dev)
        x0 = (torch.rand(g, generator=gen) * (sc["w"] - cw + 1)).long().clamp(max=sc["w"] - cw).to(dev)
        y0 = (torch.rand(g, generator=gen) * (sc["h"] - ch + 1)).long().clamp(max=sc["h"] - ch).to(dev)
        d = gather_crop(sc["depth"], a, y0, x0, ch, cw)  # [g, ch, cw]
        T = torch.linalg.inv(sc["poses"][b]) @ sc["poses"][a]  # ref -> live
        fx, fy, cx, cy = sc["k"]
        # mean flow of the ref window's valid pixels (4-px grid) that land inside the live image
        z = d[:, ::4, ::4].double()
        yy, xx = torch.meshgrid(torch.arange(0, ch, 4, device=dev, dtype=torch.float64),
                                torch.arange(0, cw, 4, device=dev, dtype=torch.float64), indexing="ij")
        X = xx[None] + x0[:, None, None].double()
        Y = yy[None] + y0[:, None, None].double()
        pc = torch.stack([(X - cx) / fx * z, (Y - cy) / fy * z, z], 1).reshape(g, 3, -1)
        q = T[:, :3, :3] @ pc + T[:, :3, 3:]
        u = fx * q[:, 0] / q[:, 2].clamp(min=1e-9) + cx
        v = fy * q[:, 1] / q[:, 2].clamp(min=1e-9) + cy
        ok = (z.reshape(g, -1) > 0) & (q[:, 2] > 1e-6) & (u >= 0) & (v >= 0) & (u <= sc["w"] - 1) & (v <= sc["h"] - 1)
        n = ok.sum(1).clamp(min=1)
        du = torch.where(ok, u - X.reshape(g, -1), 0).sum(1) / n
        dv = torch.where(ok, v - Y.reshape(g, -1), 0).sum(1) / n
        xl = (x0.double() + du).round().long().clamp(0, sc["w"] - cw)
        yl = (y0.double() + dv).round().long().clamp(0, sc["h"] - ch)
        ref = gather_crop(sc["rgb"], a, y0, x0, ch, cw)
        live = gather_crop(sc["rgb"], b, yl, xl, ch, cw)
        kk = torch.tensor([fx, fy, cx, cy], device=dev, dtype=torch.float64)
        cam_r = kk.repeat(g, 1)
        cam_r[:, 2] -= x0.double()
        cam_r[:, 3] -= y0.double()
        cam_l = kk.repeat(g, 1)
        cam_l[:, 2] -= xl.double()
        cam_l[:, 3] -= yl.double()
        out.append((ref, live, d, cam_r, cam_l, T))
    ref, live, d, cr, cl, T = (torch.cat(t) for t in zip(*out))
    ref = ref.permute(0, 3, 1, 2).float()
    live = live.permute(0, 3, 1, 2).float()
    if aug:
        ref, live = augment(ref, gen), augment(live, gen)
    return ref, live, d, cr, cl, T


def augment(x, gen):
    """SPEC §13.5: clamp(g I + b + n, 0, 255), g ~ U[0.8, 1.2], b ~ U[-15, 15] per frame,
    n ~ U[-2 sqrt 3, 2 sqrt 3] per value."""
    B = x.shape[0]
    dev = x.device
    g = (0.8 + 0.4 * torch.rand(B, 1, 1, 1, generator=gen)).to(dev)
    b = (-15 + 30 * torch.rand(B, 1, 1, 1, generator=gen)).to(dev)
    n = (torch.rand(x.shape, device=dev) * 2 - 1) * 2 * math.sqrt(3)
    return (g * x + b + n).clamp(0, 255)


# ---------------------------------------------------------------- loss


def bins_rho(cfg, dev):
    k = cfg["bins"]
    rho = cfg["rho_min"] + torch.arange(k, dtype=torch.float64, device=dev) * (cfg["rho_max"] - cfg["rho_min"]) / (k - 1)
    rho[-1] = cfg["rho_max"]
    return rho


def geometry(depth, cr, cl, T, level, rho, cfg, hw):
    """Batched float64 warp of one level (SPEC §13.1, §2.4, §2.6): used [B,N], target [B,N],
    rho* [B,N], grid [B,N,K,2] (f32), ok [B,N,K]."""
    s = 0.5**level
    h, w = hw
    dev = depth.device
    B = depth.shape[0]
    z = depth[:, :: 2**level, :: 2**level].double().reshape(B, -1)
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64, device=dev),
                            torch.arange(w, dtype=torch.float64, device=dev), indexing="ij")
    fx, fy, cx, cy = (cr[:, i, None] * s for i in range(4))
    ray = torch.stack([(xs.reshape(1, -1) - cx) / fx, (ys.reshape(1, -1) - cy) / fy, torch.ones(B, h * w, dtype=torch.float64, device=dev)], 1)
    p0 = T[:, :3, :3] @ ray  # [B,3,N]
    t = T[:, :3, 3]  # [B,3]
    lfx, lfy, lcx, lcy = (cl[:, i] * s for i in range(4))

    def proj(rho_):  # rho_ [B,N,...]
        extra = rho_.dim() - 2
        pp = [p0[:, i].reshape(B, -1, *([1] * extra)) + rho_ * t[:, i].reshape(B, *([1] * (extra + 1))) for i in range(3)]
        shp = lambda a: a.reshape(B, *([1] * (extra + 1)))
        front = (pp[2] > 0) & torch.isfinite(pp[2])
        u = shp(lfx) * pp[0] / pp[2] + shp(lcx)
        v = shp(lfy) * pp[1] / pp[2] + shp(lcy)
        ins = front & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
        return u, v, ins

    valid = torch.isfinite(z) & (z > 0)
    rho_star = torch.where(valid, 1 / torch.where(valid, z, 1.0), -1.0)
    used = valid & (rho_star >= cfg["rho_min"]) & (rho_star <= cfg["rho_max"])
    _, _, ins = proj(rho_star)
    used &= ins
    step = (cfg["rho_max"] - cfg["rho_min"]) / (cfg["bins"] - 1)
    target = torch.floor((rho_star - cfg["rho_min"]) / step + 0.5).long().clamp(0, cfg["bins"] - 1)
    u, v, ok = proj(rho.reshape(1, 1, -1).expand(B, h * w, -1))
    grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * v / max(h - 1, 1) - 1], -1)
    grid = torch.where(ok[..., None], grid, 0.0)  # float64; scale_loss casts to the features dtype
    return used, target, rho_star, grid, ok


def scale_loss(fr, fl, geo, rho, cfg):
    """Per-pair mean loss of one scale [B]; fr, fl [B,C,h,w]."""
    used, target, rho_star, grid, ok = geo
    B, C = fr.shape[:2]
    f_u = fr.reshape(B, C, -1)  # [B,C,N]
    dt = fr.dtype
    smp = F.grid_sample(fl, grid.to(dt), mode="bilinear", align_corners=True)  # [B,C,N,K]
    e = ((f_u[..., None] - smp) ** 2).sum(1)  # [B,N,K]
    e = torch.where(ok, e, cfg["outside_cost"])
    logp = torch.log_softmax(-e, -1)
    p = logp.exp()
    onehot = torch.zeros_like(ok).scatter_(2, target[..., None], True)
    ce = -logp.gather(2, target[..., None])[..., 0]
    ce = ce - torch.where(onehot, 0.0, torch.log(torch.clamp(1 - p, min=cfg["prob_floor"]))).sum(2)
    rho_hat = p @ rho.to(dt)
    d_hat = 1 / torch.clamp(rho_hat, min=cfg["rho_floor"])
    rs = torch.where(used, rho_star, 1.0).to(dt)
    loss = ce + cfg["lambda_rho"] * (rho_hat - rs) ** 2 + cfg["lambda_d"] * (d_hat - 1 / rs) ** 2
    n = used.sum(1)
    per_pair = torch.where(used, loss, 0.0).sum(1) / n.clamp(min=1)
    with torch.no_grad():
        wta = e.argmin(2)
        zt = 1 / rs
        zw = 1 / rho[wta].to(dt).clamp(min=1e-6)
        good = (torch.maximum(zw / zt, zt / zw) < 1.25) & used
    return per_pair, n, good.sum()


def forward(net, mean, s, imgs):
    """Every block output and the aggregated features, each cropped to its level:
    `benches/compare/train_torch.forward` (SPEC §8.1-8.2) as one list [(level, maps)], L last."""
    blocks, agg = train_torch.forward(net, mean, s, imgs)
    return blocks + [agg]


# cuDNN's grid_sample refuses tensors of 2^31 elements or more: pairs are taken in chunks below it.
MAX_SAMPLES = 2**31 - 1


def objective(net, mean, s, ref, live, depth, cr, cl, T, rho, cfg, checkpointed=True):
    B = ref.shape[0]
    outs = forward(net, mean, s, torch.cat([ref, live]))
    total = 0
    per_scale, good, pix = [], 0, 0
    geos = {}
    for level, f in outs:
        hw = f.shape[2:]
        if level not in geos:
            with torch.no_grad():
                geos[level] = geometry(depth, cr, cl, T, level, rho, cfg, hw)
        fr, fl = f[:B], f[B:]
        per_pair = f.shape[1] * hw[0] * hw[1] * cfg["bins"]
        step = max(1, min(B, MAX_SAMPLES // per_pair))
        pps, ns, gs = [], [], []
        for b0 in range(0, B, step):
            sl = slice(b0, min(B, b0 + step))
            geo = tuple(g[sl] for g in geos[level])
            if checkpointed:
                r = torch.utils.checkpoint.checkpoint(scale_loss, fr[sl], fl[sl], geo, rho, cfg, use_reentrant=False)
            else:
                r = scale_loss(fr[sl], fl[sl], geo, rho, cfg)
            pps.append(r[0])
            ns.append(r[1])
            gs.append(r[2])
        pp, n, g = torch.cat(pps), torch.cat(ns), sum(gs)
        total = total + pp
        per_scale.append(float(pp.detach().mean()))
        good, pix = int(g), int(n.sum())  # the last scale is L
    return total.mean(), per_scale, good / max(pix, 1)


# ---------------------------------------------------------------- optimiser and files


def lr_at(t, total, o):
    if t <= o["warmup"]:
        return o["lr"] * t / max(o["warmup"], 1)
    prog = min((t - o["warmup"]) / max(total - o["warmup"], 1), 1.0)
    return o["lr"] * (o["lr_final_fraction"] + (1 - o["lr_final_fraction"]) * 0.5 * (1 + math.cos(math.pi * prog)))


def save_safetensors(path, tensors, meta):
    """SPEC §8.4 writer: keys sorted with __metadata__ first, header padded to 8, data in order."""
    header = {"__metadata__": meta}
    off, blobs = 0, []
    for name, t in tensors:
        b = t.detach().float().cpu().contiguous().numpy().astype("<f4").tobytes()
        header[name] = {"dtype": "F32", "shape": list(t.shape), "data_offsets": [off, off + len(b)]}
        off += len(b)
        blobs.append(b)
    keys = ["__metadata__"] + sorted(k for k in header if k != "__metadata__")
    text = "{" + ",".join(json.dumps(k) + ":" + json.dumps(header[k], separators=(",", ":")) for k in keys) + "}"
    text += " " * (-len(text) % 8)
    tmp = Path(str(path) + ".tmp")
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text.encode())
        for b in blobs:
            f.write(b)
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--init", required=True, help="initial weights (densefeat init-weights) or --resume checkpoint")
    ap.add_argument("--training-init", action="store_true", help="divide each conv1's image-channel weights by 64 (SPEC §13.4)")
    ap.add_argument("--resume", action="store_true", help="--init is a final_checkpoint.safetensors: load Adam state and step")
    ap.add_argument("--pack", nargs="*", default=[], help="folders written by pack.py (training scenes only)")
    ap.add_argument("--synth", nargs="*", default=[], help="DeepVideoMVS folders (rendered training scenes)")
    ap.add_argument("--mix", default="0.25,0.25,0.50", help="weights of: first pack, second pack, ..., all synth together")
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, help="total steps of the schedule (default: from --budget-s)")
    ap.add_argument("--budget-s", type=float, default=420, help="wall-clock budget for the steps")
    ap.add_argument("--hard-stop-s", type=float, help="stop (and save) at this wall time even mid-schedule (default 1.1 x budget)")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--crop", default="256x192")
    ap.add_argument("--bins", type=int, default=256)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--clip", type=float, default=5000.0)
    ap.add_argument("--weight-decay", type=float, default=1e-4)
    ap.add_argument("--snap-every", type=int, default=0, help="snapshot period (default: total/8)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-checkpointing", action="store_true")
    a = ap.parse_args()
    dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.time()
    cw, ch = map(int, a.crop.split("x"))
    rule = dict(min_baseline=0.05, max_baseline=0.5, max_rot=30.0, min_overlap=0.6)
    cfg = dict(bins=a.bins, rho_min=0.0, rho_max=4.0, outside_cost=10.0, prob_floor=1e-6, rho_floor=0.1,
               lambda_rho=5.0, lambda_d=1.0)
    scenes, names = [], []
    for d in a.pack:
        scenes.append(load_pack(d, dev))
    synth = [load_dvmvs(d, dev) for d in a.synth]
    pairs = [pair_list(sc, rule) for sc in scenes]
    spairs = [pair_list(sc, rule) for sc in synth]
    mix = [float(x) for x in a.mix.split(",")]
    weights = []
    for i, sc in enumerate(scenes):
        print(f"scene {sc['name']}: {sc['rgb'].shape[0]} frames {sc['w']}x{sc['h']}, {len(pairs[i])} pairs", flush=True)
        weights.append(mix[i] if pairs[i] else 0.0)
    n_s = sum(1 for p in spairs if p)
    print(f"synthetic: {len(synth)} scenes, {sum(map(len, spairs))} pairs", flush=True)
    for sc, p in zip(synth, spairs):
        scenes.append(sc)
        pairs.append(p)
        weights.append(mix[-1] / n_s if p and n_s else 0.0)
    keep = [i for i, (sc, p) in enumerate(zip(scenes, pairs)) if p and sc["w"] >= cw and sc["h"] >= ch]
    scenes = [scenes[i] for i in keep]
    pairs = [pairs[i] for i in keep]
    wts = torch.tensor([weights[i] for i in keep], dtype=torch.float64)
    print(f"data ready in {time.time() - t_start:.1f} s", flush=True)

    net, mean, _, s = build(a.init)
    net = net.to(dev).train()
    mean = mean.to(dev)
    _, meta = read_safetensors(a.init)
    params = list(net.named_parameters())
    m = {n: torch.zeros_like(p) for n, p in params}
    v = {n: torch.zeros_like(p) for n, p in params}
    step0 = 0
    if a.training_init:
        # SPEC §13.4 (train::trainer::training_init): image-channel weights of each conv1 / 64.
        with torch.no_grad():
            c = int(meta["channels"])
            for k, blk in enumerate(net.blocks):
                blk.conv1.weight[:, (0 if k == 0 else c):] /= 64.0
    if a.resume:
        t, meta = read_safetensors(a.init)
        for n, _ in params:
            m[n].copy_(t[f"adam.m.{n}"])
            v[n].copy_(t[f"adam.v.{n}"])
        step0 = int(meta["step"])
    rho = bins_rho(cfg, dev)
    gen = torch.Generator().manual_seed(a.seed)
    o = dict(lr=a.lr, warmup=a.warmup, lr_final_fraction=0.05)  # warm-up capped at 10 % of the run below
    b1, b2, eps = 0.9, 0.999, 1e-8

    def one_step(t, total):
        ref, live, depth, cr, cl, T = make_batch(scenes, pairs, wts, a.batch, (cw, ch), gen, True)
        net.zero_grad(set_to_none=True)
        loss, per_scale, d125 = objective(net, mean, s, ref, live, depth, cr, cl, T, rho, cfg, not a.no_checkpointing)
        loss.backward()
        with torch.no_grad():
            gn = torch.sqrt(sum((p.grad.double() ** 2).sum() for _, p in params)).item()
            clip = min(1.0, a.clip / gn) if gn > 0 else 1.0
            lr = lr_at(t, total, o)
            bc1, bc2 = 1 - b1**t, 1 - b2**t
            for n, p in params:
                g = p.grad * clip
                m[n].mul_(b1).add_(g, alpha=1 - b1)
                v[n].mul_(b2).addcmul_(g, g, value=1 - b2)
                upd = (m[n] / bc1) / ((v[n] / bc2).sqrt() + eps)
                decay = lr * a.weight_decay if n.endswith("weight") else 0.0
                p.mul_(1 - decay).sub_(upd, alpha=lr)
        return float(loss.detach()), per_scale, d125, gn, clip < 1.0, lr

    # Probe the step time, then fix the schedule length from the budget.
    total = a.steps
    log_rows = []
    t = step0
    if total is None:
        tp = time.time()
        probe = 5
        for _ in range(probe):
            t += 1
            r = one_step(t, 10**9)  # warm-up lr only (t <= warmup)
            log_rows.append((t, r, time.time() - t_start))
        if dev.type == "cuda":
            torch.cuda.synchronize()
        per = (time.time() - tp) / probe
        total = max(int((a.budget_s - (time.time() - t_start)) / per) + t, t + 1)
        print(f"probe: {per * 1e3:.1f} ms/step -> schedule of {total} steps ({total * a.batch} pairs)", flush=True)
    hard_stop = a.hard_stop_s or 1.1 * a.budget_s
    if resized:
        o["warmup"] = min(a.warmup, max(1, total // 10))
    resized = a.steps is not None

    def names_meta(step):
        return {"format": "densefeat-featurenet-v1", "blocks": meta["blocks"], "channels": meta["channels"],
                "b1_stride": meta["b1_stride"], "input_mean": meta["input_mean"],
                "provenance": f"tools/train_gpu/train_gpu.py step={step} of {total} batch={a.batch} crop={a.crop} bins={a.bins} lr={a.lr} seed={a.seed}"}

    def snap(step):
        save_safetensors(out / f"snap_{step:06d}.safetensors", [(n, p) for n, p in params], names_meta(step))

    with open(out / "log.csv", "w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(["step", "lr", "loss", "loss_L1", "loss_L2", "loss_L3", "loss_L4", "loss_L5", "loss_L", "delta125_wta_L",
                     "grad_norm", "clipped", "elapsed_s"])
        def row(tt, r, el):
            loss, ps, d125, gn, clipped, lr = r
            wr.writerow([tt, f"{lr:.3e}", f"{loss:.5f}"] + [f"{x:.5f}" for x in ps] + [f"{d125:.4f}", f"{gn:.2f}", int(clipped), f"{el:.1f}"])
        for tt, r, el in log_rows:
            row(tt, r, el)
        snap_every = a.snap_every or max(total // 8, 1)
        t_mark, s_mark = time.time(), t
        while t < total:
            t += 1
            r = one_step(t, total)
            row(t, r, time.time() - t_start)
            if not resized and t - s_mark == 40:
                # Re-measure once the other processes on the GPU are running too, still inside the
                # warm-up (the cosine part of the schedule has not started), and fix the length.
                if dev.type == "cuda":
                    torch.cuda.synchronize()
                per = (time.time() - t_mark) / 40
                total = max(int((a.budget_s - (time.time() - t_start)) / per) + t, t + 1)
                snap_every = a.snap_every or max(total // 8, 1)
                o["warmup"] = min(a.warmup, max(t, total // 10))
                resized = True
                print(f"re-measured: {per * 1e3:.1f} ms/step -> schedule of {total} steps ({total * a.batch} pairs)", flush=True)
            if time.time() - t_start > hard_stop:
                print(f"hard stop at step {t} of {total} ({time.time() - t_start:.0f} s)", flush=True)
                snap(t)
                break
            if t % 50 == 0:
                f.flush()
                print(f"step {t}/{total} loss {r[0]:.3f} d125(L,wta) {r[2]:.3f} gn {r[3]:.1f} lr {r[5]:.2e} "
                      f"{time.time() - t_start:.0f} s", flush=True)
            if t % snap_every == 0 or t == total:
                snap(t)
    fin = [(n, p) for n, p in params] + [(f"adam.m.{n}", m[n]) for n, _ in params] + [(f"adam.v.{n}", v[n]) for n, _ in params]
    meta_f = names_meta(t)
    meta_f.update({"format": "densefeat-gpu-checkpoint-v1", "step": str(t), "adam_step": str(t)})
    save_safetensors(out / "final_checkpoint.safetensors", fin, meta_f)
    print(f"done: {t} steps, {t * a.batch} pairs, {time.time() - t_start:.0f} s", flush=True)


if __name__ == "__main__":
    sys.exit(main())
