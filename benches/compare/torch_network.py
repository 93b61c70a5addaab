#!/usr/bin/env python3
"""PyTorch beside densefeat's feature network: the module of SPEC.md §8.3, taken verbatim from
SPEC.md (so the SPEC itself is what is checked), loaded with `load_state_dict(strict=True)` from
the same safetensors file.

1. Correctness: `densefeat features IMAGE --weights W --out f.npy` against PyTorch on the same
   image, with the input handling of SPEC §8.1-8.2 (RGB 0-255 minus the file's input mean, edge
   padding at the bottom/right to a multiple of the total stride, crop of the output). Check: SPEC
   §8.7's end-to-end budget, max |a - b| / max |b| <= 1.43e-3. Exit status 1 on failure.
2. Timing, interleaved: PyTorch CPU (NCHW and channels_last, torch.set_num_threads(N),
   inference_mode, median of --runs after 3 warm-ups) beside `densefeat bench forward --size WxH
   --b1-stride S --threads N` for 320x240 and 640x480, B1 stride 1 and 2, 1 and 2 threads.

Usage: python3 benches/compare/torch_network.py [--densefeat target/release/densefeat] [--runs 20]
"""
import argparse, json, os, re, statistics, struct, subprocess, sys, tempfile, time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
BUDGET = 19 * 2 * 315 * 2.0**-23  # SPEC §8.7 for the paper's network


def spec_module():
    """Exec the python block of SPEC.md §8.3 and return its namespace."""
    spec = (ROOT / "SPEC.md").read_text()
    section = spec[spec.index("### 8.3 The PyTorch module") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    ns = {}
    exec(code, ns)
    return ns


def read_safetensors(path):
    raw = Path(path).read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    meta = header.pop("__metadata__")
    data = raw[8 + n :]
    tensors = {}
    for name, t in header.items():
        a, b = t["data_offsets"]
        assert t["dtype"] == "F32", name
        tensors[name] = torch.from_numpy(np.frombuffer(data[a:b], dtype="<f4").reshape(t["shape"]).copy())
    return tensors, meta


def build(path):
    ns = spec_module()
    tensors, meta = read_safetensors(path)
    blocks, c, s = int(meta["blocks"]), int(meta["channels"]), int(meta["b1_stride"])
    net = ns["FeatureNet"](blocks, c, s)
    net.load_state_dict(tensors, strict=True)  # names and shapes must be exactly the state_dict's
    net.eval()
    mean = torch.tensor([float(v) for v in meta["input_mean"].split(",")]).view(1, 3, 1, 1)
    return net, mean, blocks, s


def features(net, mean, blocks, s, img_hwc):
    h, w, _ = img_hwc.shape
    total = blocks - 1 + (1 if s == 2 else 0)  # SPEC §8.2: log2 of the total stride
    m = 1 << total
    hp, wp = -(-h // m) * m, -(-w // m) * m
    x = torch.from_numpy(img_hwc).permute(2, 0, 1)[None].float() - mean
    x = F.pad(x, (0, wp - w, 0, hp - h), mode="replicate")
    with torch.inference_mode():
        a, _ = net(x)
    l0 = 1 if s == 2 else 0
    return a[0, :, : -(-h // (1 << l0)), : -(-w // (1 << l0))].permute(1, 2, 0).numpy()


def densefeat_features(binary, image, weights):
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "f.npy"
        subprocess.run([binary, "features", str(image), "--weights", str(weights), "--out", str(out)], check=True, capture_output=True)
        return np.load(out)


def bench_densefeat(binary, size, stride, threads, runs):
    out = subprocess.run([binary, "bench", "forward", "--size", size, "--b1-stride", str(stride), "--threads", str(threads), "--runs", str(max(runs, 20))], check=True, capture_output=True, text=True).stdout
    row = [l for l in out.splitlines() if l.startswith(f"| {size} |")][0]
    return float(row.split("|")[5])


def bench_torch(net, size, threads, runs, channels_last):
    w, h = map(int, size.split("x"))
    # The padded input of SPEC §8.2 (densefeat's forward pads the same way inside its timing).
    m = 1 << (len(net.blocks) - 1 + (1 if net.blocks[0].conv1.stride[0] == 2 else 0))
    h, w = -(-h // m) * m, -(-w // m) * m
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    x = torch.randn(1, 3, h, w) * 50
    n = net
    if channels_last:
        n = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    times = []
    with torch.inference_mode():
        for i in range(runs + 3):
            t = time.perf_counter()
            n(x)
            if i >= 3:
                times.append((time.perf_counter() - t) * 1e3)
    if channels_last:
        net.to(memory_format=torch.contiguous_format)
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--densefeat", default=str(ROOT / "target/release/densefeat"))
    ap.add_argument("--runs", type=int, default=20)
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs must be at least 1")
    print(f"torch {torch.__version__}, numpy {np.__version__}, cpus {os.cpu_count()}, load {os.getloadavg()}")
    ok = True
    with tempfile.TemporaryDirectory() as d:
        w1 = Path(d) / "w_s1.safetensors"
        subprocess.run([args.densefeat, "init-weights", "--seed", "0", "--b1-stride", "1", "--mean-of-images", str(ROOT / "fixtures/synthetic/room_s1/images"), "--out", str(w1)], check=True, capture_output=True)
        weights = [(ROOT / "fixtures/weights/featurenet_init_seed0.safetensors", 2), (w1, 1)]
        images = [ROOT / "fixtures/synthetic/room_s1/images/00000.png"]
        tum = sorted((ROOT.parent / "shared/data/tum_fr1_rpy/rgb").glob("*.png"))
        if tum:
            images.append(tum[0])
        print("\n## Correctness: densefeat features vs PyTorch (SPEC §8.3 module, strict state_dict load)\n")
        print("| image | size | b1 stride | max abs diff | max abs feature | rel | budget | pass |")
        print("|---|---|---|---|---|---|---|---|")
        for wpath, s in weights:
            net, mean, blocks, s2 = build(wpath)
            assert s2 == s
            torch.set_num_threads(1)
            for img in images:
                rgb = np.asarray(Image.open(img).convert("RGB"), dtype=np.float32)
                ours = densefeat_features(args.densefeat, img, wpath)
                theirs = features(net, mean, blocks, s, rgb)
                assert ours.shape == theirs.shape, (ours.shape, theirs.shape)
                diff = float(np.abs(ours - theirs).max())
                mag = float(np.abs(theirs).max())
                rel = diff / mag
                ok &= rel <= BUDGET
                print(f"| {img.name} | {rgb.shape[1]}x{rgb.shape[0]} | {s} | {diff:.3e} | {mag:.3f} | {rel:.2e} | {BUDGET:.2e} | {'yes' if rel <= BUDGET else 'NO'} |")
        print(f"\n## Timing: median ms (densefeat: `bench forward`, {max(args.runs, 20)} runs; PyTorch: inference_mode, {args.runs} runs)\n")
        print("| size | b1 stride | threads | densefeat ms | torch NCHW ms | torch channels_last ms | densefeat / best torch |")
        print("|---|---|---|---|---|---|---|")
        for size in ["320x240", "640x480"]:
            for s in [2, 1]:
                net, _, _, _ = build(weights[0][0] if s == 2 else weights[1][0])
                for threads in [1, 2]:
                    ours = bench_densefeat(args.densefeat, size, s, threads, args.runs)
                    nchw = bench_torch(net, size, threads, args.runs, False)
                    cl = bench_torch(net, size, threads, args.runs, True)
                    print(f"| {size} | {s} | {threads} | {ours:.2f} | {nchw:.2f} | {cl:.2f} | {ours / min(nchw, cl):.2f} |", flush=True)
    print("\ncorrectness:", "all within the SPEC §8.7 budget" if ok else "FAILED")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
