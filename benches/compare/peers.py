#!/usr/bin/env python3
"""densefeat, ONNX Runtime and PyTorch in ONE interleaved run: issue 14's ratio table.

For each of the eight configurations (320x240 and 640x480, B1 stride 2 and 1, 1 and 2 threads) the
four sides are timed one after another, `--rounds` times, the order rotated every round so that a
change of machine load does not favour one side:

- densefeat: `densefeat bench forward --size WxH --b1-stride S --threads N --runs R` (median ms);
- ONNX Runtime: the graph of `ort_compare.py` (same network), `intra_op_num_threads = N`, median
  of R runs after 3 warm-ups; with 2 threads also a session whose workers do not spin, and the
  faster of the two counts;
- PyTorch: the SPEC §8.3 module of `torch_network.py`, `torch.set_num_threads(N)`,
  `inference_mode`, NCHW and channels_last, median of R runs after 3 warm-ups.

Each side's figure is its lowest median over the rounds. The table gives every figure and
densefeat / (the fastest peer variant): ORT (spinning or not) and PyTorch (channels_last or
NCHW). The issue asks for the better of PyTorch channels_last and ORT; taking NCHW too is stricter.
The machine-state indicator `densefeat bench gemm --threads 1` (GFLOP/s; about 200 on the idle
2-vCPU build machine) is printed before and after, with the 1-minute load average per row.

Correctness is not checked here: `ort_compare.py` and `torch_network.py` do that (and time each
peer on its own). A peer whose Python packages are missing is skipped with a message naming the
requirements file; the ratio is then to the fastest peer that ran.

Usage: python3 benches/compare/peers.py [--densefeat PATH] [--runs 20] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

try:
    import ort_compare as oc  # noqa: E402
except ImportError as e:  # onnxruntime / onnx missing
    sys.exit(f"peers.py needs ort_compare.py's packages ({e}): pip install -r benches/compare/requirements.txt")
try:
    import torch  # noqa: E402

    import torch_network as tn  # noqa: E402
except ImportError as e:
    torch, tn = None, None
    TORCH_MISSING = f"SKIPPED: PyTorch ({e}; pip install -r benches/compare/requirements-torch.txt)"

CONFIGS = [(size, stride, threads) for size in ((320, 240), (640, 480)) for stride in (2, 1) for threads in (1, 2)]


def gemm_indicator(exe: Path) -> float:
    out = oc.run_cmd([exe, "bench", "gemm", "--threads", 1])
    return float(out.strip().splitlines()[-1].strip().strip("|").split("|")[-1])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--densefeat", help="densefeat binary (default $CARGO_TARGET_DIR/release/densefeat)")
    p.add_argument("--runs", type=int, default=20, help="timed runs per measurement (`bench forward` times max(runs, 20))")
    p.add_argument("--rounds", type=int, default=3, help="interleaved rounds per configuration")
    args = p.parse_args()
    if args.runs < 1:
        p.error("--runs must be at least 1")
    if args.rounds < 1:
        p.error("--rounds must be at least 1")
    exe = oc.find_densefeat(args.densefeat)
    versions = f"onnxruntime {oc.ort.__version__}, " + (f"torch {torch.__version__}" if torch else TORCH_MISSING)
    print(f"densefeat: {exe}\n{versions}, cpus {os.cpu_count()}")
    before = gemm_indicator(exe)
    print(f"machine state: `densefeat bench gemm --threads 1` {before:.1f} GFLOP/s (idle ~200), load {os.getloadavg()}\n")
    print(f"## Median ms, lowest over {args.rounds} interleaved rounds, {args.runs} runs each\n")
    print("| size | b1 stride | threads | densefeat | ORT | ORT no-spin | torch channels_last | torch NCHW "
          "| densefeat / ORT | densefeat / torch cl | densefeat / fastest peer | load (1 min) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    with tempfile.TemporaryDirectory(prefix="densefeat-peers-") as tmpname:
        tmp = Path(tmpname)
        weights = {}
        for stride in (2, 1):
            # The bench's network: Xavier seed 0, input mean 128 (src/cli/bench.rs).
            weights[stride] = tmp / f"bench_b1s{stride}.safetensors"
            oc.run_cmd([exe, "init-weights", "--seed", 0, "--b1-stride", stride, "--mean", "128,128,128",
                        "--out", weights[stride]])
        for (w, h), stride, threads in CONFIGS:
            model = oc.build_model(oc.Config(weights[stride]), h, w)
            x = oc.to_nchw(oc.bench_pattern(h, w))
            sess = oc.session(model, threads)
            quiet = oc.session(model, threads, spin=False) if threads > 1 else None
            net = tn.build(weights[stride])[0] if tn else None
            size = f"{w}x{h}"
            sides = {
                "densefeat": lambda: oc.bench_forward_ms(exe, w, h, stride, threads, args.runs),
                "ort": lambda: oc.ort_median_ms(sess, x, args.runs),
                "ort_quiet": (lambda: oc.ort_median_ms(quiet, x, args.runs)) if quiet is not None else None,
                "torch_cl": (lambda: tn.bench_torch(net, size, threads, args.runs, True)) if tn else None,
                "torch_nchw": (lambda: tn.bench_torch(net, size, threads, args.runs, False)) if tn else None,
            }
            names = [n for n, f in sides.items() if f is not None]
            best = {n: float("inf") for n in names}
            for r in range(args.rounds):
                order = names[r % len(names):] + names[: r % len(names)]
                for n in order:
                    best[n] = min(best[n], sides[n]())
            ours = best["densefeat"]
            ort_best = min(best["ort"], best.get("ort_quiet", float("inf")))
            torch_best = min(best.get("torch_cl", float("inf")), best.get("torch_nchw", float("inf")))
            ratio = ours / min(ort_best, torch_best)
            worst = max(worst, ratio)

            def ms(name):
                return f"{best[name]:.2f}" if name in best else "—"

            vs_cl = f"{ours / best['torch_cl']:.2f}" if "torch_cl" in best else "—"
            print(f"| {size} | {stride} | {threads} | {ours:.2f} | {ms('ort')} | {ms('ort_quiet')} | "
                  f"{ms('torch_cl')} | {ms('torch_nchw')} | {ours / ort_best:.2f} | {vs_cl} | "
                  f"**{ratio:.2f}** | {os.getloadavg()[0]:.1f} |", flush=True)
            del sess, quiet, net
    after = gemm_indicator(exe)
    print(f"\nworst densefeat / fastest peer: {worst:.2f}")
    print(f"machine state after: `densefeat bench gemm --threads 1` {after:.1f} GFLOP/s, load {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
