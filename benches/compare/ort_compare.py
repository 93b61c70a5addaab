#!/usr/bin/env python3
"""Side-by-side comparison of densefeat's feature network with ONNX Runtime (CPU).

The network of SPEC.md §8 is rebuilt as an ONNX graph with `onnx.helper` from the same
safetensors file (Sub for the input mean, edge Pad at the bottom/right, Conv/Relu blocks, the
§2.1/§7.4 tent downsampling as an edge Pad + depthwise 3x3 stride-2 Conv, Concat, ConvTranspose
with output_padding, Add, and a Slice for the crop of §8.2), in NCHW as ORT expects.

1. Correctness: `densefeat features IMAGE --weights W --out f.npy` against ORT on the same image,
   for B1 stride 2 (the shipped weights) and B1 stride 1 (`densefeat init-weights --b1-stride 1`),
   on the synthetic fixture frame, a 640x480 TUM frame (if present) and an odd-sized crop (padding
   and cropping). The check is SPEC §8.7's end-to-end budget,
   `max |a - b| / max |b| <= D * 2 * K_max * eps`, `D = 4 blocks - 1`, `K_max = 9 (channels + 3)`
   (1.4e-3 for the paper's network). Exit status 1 if any check fails.
2. Timing, interleaved per configuration: ORT (intra_op_num_threads 1 and 2, sequential
   execution, all graph optimisations) median ms over --runs runs after warm-up, beside
   `densefeat bench forward --size WxH --b1-stride S --threads N` (median ms parsed from its
   table), on the same network (Xavier seed 0, input mean 128, as the bench uses).
3. Peak resident memory of `densefeat features` on a 640x480 image (getrusage of the child).

Usage: python3 benches/compare/ort_compare.py [--densefeat PATH] [--runs N] [--rounds N]
       [--skip-timing] [--skip-correctness]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper
from PIL import Image
from safetensors.numpy import load_file

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_WEIGHTS = ROOT / "fixtures/weights/featurenet_init_seed0.safetensors"
SYNTH_IMAGE = ROOT / "fixtures/synthetic/room_s1/images/00000.png"
SYNTH_DIR = ROOT / "fixtures/synthetic/room_s1/images"
TUM_DIR = ROOT.parent / "shared/data/tum_fr1_rpy/rgb"
EPS_F32 = float(np.finfo(np.float32).eps)


# --------------------------------------------------------------------------------------------
# Weights and the ONNX graph
# --------------------------------------------------------------------------------------------


def read_metadata(path: Path) -> dict:
    with open(path, "rb") as f:
        (n,) = struct.unpack("<Q", f.read(8))
        header = json.loads(f.read(n))
    return header["__metadata__"]


class Config:
    def __init__(self, path: Path):
        meta = read_metadata(path)
        if meta.get("format") != "densefeat-featurenet-v1":
            raise SystemExit(f"{path}: not a densefeat-featurenet-v1 file")
        self.blocks = int(meta["blocks"])
        self.channels = int(meta["channels"])
        self.b1_stride = int(meta["b1_stride"])
        self.input_mean = np.array([float(v) for v in meta["input_mean"].split(",")], np.float32)
        self.tensors = load_file(str(path))

    def level(self, k: int) -> int:
        """Level of block k's output (SPEC §8.1)."""
        return k + (1 if self.b1_stride == 2 else 0)

    def budget(self) -> float:
        """SPEC §8.7 end-to-end relative budget D * 2 K_max eps."""
        d = 4 * self.blocks - 1
        k_max = 9 * (self.channels + 3)
        return d * 2 * k_max * EPS_F32


def build_model(cfg: Config, h: int, w: int) -> onnx.ModelProto:
    """The §8 network for one [1, 3, h, w] RGB input (0-255, NCHW); output [1, C, h_0, w_0]."""
    s = cfg.level(cfg.blocks - 1)
    hp = -(-h // 2**s) * 2**s
    wp = -(-w // 2**s) * 2**s
    nodes, inits = [], []

    def const(name, arr):
        inits.append(numpy_helper.from_array(np.ascontiguousarray(arr), name))
        return name

    const("mean", cfg.input_mean.reshape(1, 3, 1, 1))
    nodes.append(helper.make_node("Sub", ["image", "mean"], ["centred"]))
    # Bottom/right edge replication to a multiple of 2^S (§8.2).
    const("pad_br", np.array([0, 0, 0, 0, 0, 0, hp - h, wp - w], np.int64))
    nodes.append(helper.make_node("Pad", ["centred", "pad_br"], ["pyr0"], mode="edge"))

    # Tent downsampling (§2.1, §7.4): edge pad 1, depthwise 3x3 stride-2 conv.
    t = np.array([0.25, 0.5, 0.25], np.float32)
    const("tent", np.broadcast_to(np.outer(t, t), (3, 1, 3, 3)).astype(np.float32))
    const("pad1", np.array([0, 0, 1, 1, 0, 0, 1, 1], np.int64))
    pyr = ["pyr0"]

    def image_at(level: int) -> str:
        while len(pyr) <= level:
            src, i = pyr[-1], len(pyr)
            nodes.append(helper.make_node("Pad", [src, "pad1"], [f"pyr{i}_padded"], mode="edge"))
            nodes.append(
                helper.make_node(
                    "Conv", [f"pyr{i}_padded", "tent"], [f"pyr{i}"],
                    kernel_shape=[3, 3], strides=[2, 2], pads=[0, 0, 0, 0], group=3,
                )
            )
            pyr.append(f"pyr{i}")
        return pyr[level]

    def conv(x, name, stride, relu):
        wname = const(f"{name}.weight", cfg.tensors[f"{name}.weight"])
        bname = const(f"{name}.bias", cfg.tensors[f"{name}.bias"])
        y = f"{name}.out"
        nodes.append(
            helper.make_node(
                "Conv", [x, wname, bname], [y], kernel_shape=[3, 3], strides=[stride, stride],
                pads=[1, 1, 1, 1],
            )
        )
        if relu:
            nodes.append(helper.make_node("Relu", [y], [f"{name}.relu"]))
            return f"{name}.relu"
        return y

    outs = []
    for k in range(cfg.blocks):
        if k == 0:
            x, stride = "pyr0", cfg.b1_stride
        else:
            x, stride = f"cat{k}", 2
            # features first, then the image at the previous block's level
            nodes.append(helper.make_node("Concat", [outs[-1], image_at(cfg.level(k - 1))], [x], axis=1))
        x = conv(x, f"blocks.{k}.conv1", stride, True)
        x = conv(x, f"blocks.{k}.conv2", 1, True)
        x = conv(x, f"blocks.{k}.conv3", 1, False)
        outs.append(x)

    a = outs[-1]
    for k in reversed(range(cfg.blocks - 1)):
        name = f"deconvs.{k}"
        wname = const(f"{name}.weight", cfg.tensors[f"{name}.weight"])
        bname = const(f"{name}.bias", cfg.tensors[f"{name}.bias"])
        nodes.append(
            helper.make_node(
                "ConvTranspose", [a, wname, bname], [f"{name}.out"], kernel_shape=[5, 5],
                strides=[2, 2], pads=[2, 2, 2, 2], output_padding=[1, 1],
            )
        )
        nodes.append(helper.make_node("Add", [outs[k], f"{name}.out"], [f"a{k}"]))
        a = f"a{k}"

    l0 = cfg.level(0)
    h0, w0 = -(-h // 2**l0), -(-w // 2**l0)
    const("crop_starts", np.array([0, 0], np.int64))
    const("crop_ends", np.array([h0, w0], np.int64))
    const("crop_axes", np.array([2, 3], np.int64))
    nodes.append(helper.make_node("Slice", [a, "crop_starts", "crop_ends", "crop_axes"], ["features"]))

    graph = helper.make_graph(
        nodes, "densefeat_featurenet",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, h, w])],
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, [1, cfg.channels, h0, w0])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def session(model: onnx.ModelProto, threads: int, spin: bool = True) -> ort.InferenceSession:
    so = ort.SessionOptions()
    if not spin:
        # ORT's intra-op workers busy-wait by default; on an oversubscribed machine that steals
        # the CPU its own other thread needs.
        so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def to_nchw(hwc: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(hwc.astype(np.float32).transpose(2, 0, 1)[None])


def load_rgb(path: Path) -> np.ndarray:
    """[H, W, 3] f32 0-255, as densefeat's `image::load_rgb` (alpha dropped, grey replicated)."""
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32)


# --------------------------------------------------------------------------------------------
# densefeat
# --------------------------------------------------------------------------------------------


def find_densefeat(given: str | None) -> Path:
    if given:
        return Path(given)
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    exe = target / "release/densefeat"
    if not exe.exists():
        raise SystemExit(f"{exe} not found: run `cargo build --release` (or pass --densefeat)")
    return exe


def run_cmd(cmd: list) -> str:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"command failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stderr}")
    return r.stdout


def densefeat_features(exe: Path, image: Path, weights: Path, out: Path) -> np.ndarray:
    run_cmd([exe, "features", image, "--weights", weights, "--out", out])
    return np.load(out)


def bench_forward_ms(exe: Path, w: int, h: int, stride: int, threads: int, runs: int) -> float:
    # `bench forward` needs at least 20 runs for a stable median.
    out = run_cmd([exe, "bench", "forward", "--size", f"{w}x{h}", "--b1-stride", stride,
                   "--threads", threads, "--runs", max(runs, 20)])
    # | size | b1 stride | threads | runs | median ms | ...
    for line in out.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells and re.fullmatch(r"\d+x\d+", cells[0]):
            return float(cells[4])
    raise SystemExit(f"cannot parse `densefeat bench forward` output:\n{out}")


def bench_pattern(h: int, w: int) -> np.ndarray:
    """The test image of `densefeat bench forward` (src/cli/bench.rs `pattern`), [H, W, 3]."""
    y, x, c = np.meshgrid(np.arange(h), np.arange(w), np.arange(3), indexing="ij")
    return ((x * 7 + y * 13 + c * 61 + (x * y) % 17) % 256).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Parts
# --------------------------------------------------------------------------------------------


def correctness(exe: Path, weights_by_stride: dict, images: list, tmp: Path) -> bool:
    ok = True
    print("## Correctness: densefeat features vs ONNX Runtime (1 thread)\n")
    print("| image | size | b1 stride | features shape | max abs diff | max abs feature "
          "| rel (diff / max) | SPEC §8.7 budget | pass |")
    print("|---|---|---|---|---|---|---|---|---|")
    for stride, weights in weights_by_stride.items():
        cfg = Config(weights)
        for image in images:
            rgb = load_rgb(image)
            h, w, _ = rgb.shape
            ours = densefeat_features(exe, image, weights, tmp / "f.npy")
            (theirs,) = session(build_model(cfg, h, w), 1).run(None, {"image": to_nchw(rgb)})
            theirs = theirs[0].transpose(1, 2, 0)  # NCHW -> HWC
            if ours.shape != theirs.shape:
                print(f"| {image.name} | {w}x{h} | {stride} | {ours.shape} vs {theirs.shape} "
                      "| — | — | — | — | **FAIL (shape)** |")
                ok = False
                continue
            diff = float(np.max(np.abs(ours.astype(np.float64) - theirs)))
            mag = float(np.max(np.abs(theirs)))
            rel = diff / mag
            budget = cfg.budget()
            passed = bool(rel <= budget) and np.all(np.isfinite(ours))
            ok &= passed
            print(f"| {image.name} | {w}x{h} | {stride} | {list(ours.shape)} | {diff:.3e} | "
                  f"{mag:.3f} | {rel:.2e} | {budget:.2e} | {'yes' if passed else '**FAIL**'} |")
    print()
    return ok


def ort_median_ms(sess: ort.InferenceSession, x: np.ndarray, runs: int, warmup: int = 3) -> float:
    feed = {"image": x}
    for _ in range(warmup):
        sess.run(None, feed)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        sess.run(None, feed)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def timing(exe: Path, weights_by_stride: dict, runs: int, rounds: int) -> None:
    sizes = [(320, 240), (640, 480)]
    print(f"## Timing: median ms, {runs} runs after warm-up, best (lowest median) of {rounds} "
          "rounds, interleaved per configuration\n")
    print("| size | b1 stride | threads | densefeat ms | ORT ms | densefeat / ORT "
          "| ORT no-spin ms | densefeat / ORT no-spin | load (1 min) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for w, h in sizes:
        for stride in (2, 1):
            cfg = Config(weights_by_stride[stride])
            model = build_model(cfg, h, w)
            x = to_nchw(bench_pattern(h, w))
            for threads in (1, 2):
                sess = session(model, threads)
                # with one thread there is nothing to spin for
                quiet = session(model, threads, spin=False) if threads > 1 else None
                ours, theirs, theirs_quiet = [], [], []
                for r in range(rounds):
                    # alternate which goes first, so a load change does not favour one side
                    if r % 2 == 0:
                        theirs.append(ort_median_ms(sess, x, runs))
                    ours.append(bench_forward_ms(exe, w, h, stride, threads, runs))
                    if quiet is not None:
                        theirs_quiet.append(ort_median_ms(quiet, x, runs))
                    if r % 2 == 1:
                        theirs.append(ort_median_ms(sess, x, runs))
                d, o = min(ours), min(theirs)
                q = f"{min(theirs_quiet):.2f} | {d / min(theirs_quiet):.2f}" if theirs_quiet else "— | —"
                load = os.getloadavg()[0]
                print(f"| {w}x{h} | {stride} | {threads} | {d:.2f} | {o:.2f} | {d / o:.2f} | {q} | "
                      f"{load:.1f} |", flush=True)
                del sess, quiet
    print()


def memory(exe: Path, image: Path, tmp: Path) -> None:
    """Peak RSS of one `densefeat features` run, from getrusage(RUSAGE_CHILDREN) in a fresh
    Python child (so no earlier child of this process counts)."""
    code = (
        "import resource, subprocess, sys\n"
        "subprocess.run(sys.argv[1:], check=True, capture_output=True)\n"
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    )
    out = run_cmd([sys.executable, "-c", code, exe, "features", image, "--out", tmp / "m.npy"])
    kib = int(out.strip())
    h, w, _ = load_rgb(image).shape
    print("## Memory\n")
    print(f"peak RSS of `densefeat features` on {image.name} ({w}x{h}): {kib / 1024:.1f} MiB "
          f"({kib} KiB; target < 200 MB)\n")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--densefeat", help="densefeat binary (default $CARGO_TARGET_DIR/release/densefeat)")
    p.add_argument("--weights", default=str(DEFAULT_WEIGHTS), help="B1-stride-2 weights to check")
    p.add_argument("--tum-image", help="a 640x480 TUM frame (default: first of ../shared/data/tum_fr1_rpy/rgb)")
    p.add_argument("--runs", type=int, default=20, help="timed runs per measurement (densefeat's `bench forward` times max(runs, 20))")
    p.add_argument("--rounds", type=int, default=2, help="interleaved rounds per configuration")
    p.add_argument("--skip-timing", action="store_true")
    p.add_argument("--skip-correctness", action="store_true")
    args = p.parse_args()
    if args.runs < 1:
        p.error("--runs must be at least 1")
    exe = find_densefeat(args.densefeat)
    print(f"densefeat: {exe}\nonnxruntime {ort.__version__}, onnx {onnx.__version__}, "
          f"numpy {np.__version__}, cpus {os.cpu_count()}, load {os.getloadavg()}\n")

    with tempfile.TemporaryDirectory(prefix="densefeat-compare-") as tmpname:
        tmp = Path(tmpname)
        # B1 stride 1 weights: the same Xavier seed 0, the same fixture mean.
        s1 = tmp / "featurenet_init_seed0_b1s1.safetensors"
        run_cmd([exe, "init-weights", "--seed", 0, "--b1-stride", 1, "--mean-of-images", SYNTH_DIR,
                 "--out", s1])
        images = [SYNTH_IMAGE]
        tum = Path(args.tum_image) if args.tum_image else (
            min(TUM_DIR.glob("*.png")) if TUM_DIR.is_dir() else None)
        if tum is not None:
            images.append(tum)
        else:
            print(f"(no TUM frame under {TUM_DIR}: skipped)\n")
        # An odd size, to exercise the bottom/right padding and the crop (§8.2).
        odd = tmp / "odd_333x251.png"
        Image.fromarray(load_rgb(images[-1])[:251, :333].astype(np.uint8)).save(odd)
        images.append(odd)

        ok = True
        if not args.skip_correctness:
            ok = correctness(exe, {2: Path(args.weights), 1: s1}, images, tmp)
        memory(exe, images[1] if tum is not None else images[0], tmp)
        if not args.skip_timing:
            # The bench's network: Xavier seed 0, input mean 128 (src/cli/bench.rs).
            bench_w = {}
            for stride in (2, 1):
                bench_w[stride] = tmp / f"bench_b1s{stride}.safetensors"
                run_cmd([exe, "init-weights", "--seed", 0, "--b1-stride", stride,
                         "--mean", "128,128,128", "--out", bench_w[stride]])
            timing(exe, bench_w, args.runs, args.rounds)
    if not ok:
        print("CORRECTNESS CHECK FAILED", file=sys.stderr)
        return 1
    print("correctness: all within the SPEC §8.7 end-to-end budget")
    return 0


if __name__ == "__main__":
    sys.exit(main())
