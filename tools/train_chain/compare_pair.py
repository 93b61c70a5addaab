#!/usr/bin/env python3
"""Two wide_validation.sh runs of the same methods, scene by scene: per method, mean δ<1.25 and rms over
all scenes and per group (classic renders s2..., realistic renders r2..., the real room), how many
scenes B is better / worse on (δ<1.25), and the scenes that move by more than 0.02.

    python3 tools/train_chain/compare_pair.py A B [--scene S ...]

A and B are tags (runs/valwide/TAG/all.csv) or csv files (e.g. docs/training/wide_validation/mf4so.csv);
only the (scene, method) rows both hold are compared. --scene prints those scenes' rows in full.
"""
import csv
import os
import sys


def load(arg):
    path = arg if arg.endswith(".csv") else f"runs/valwide/{arg}/all.csv"
    if not os.path.isfile(path):
        sys.exit(f"compare_pair.py: {path}: no such file")
    return {(r["scene"], r["method"]): r for r in csv.DictReader(open(path))}


def mean(xs):
    return sum(xs) / len(xs) if xs else float("nan")


def group(scene):
    if scene.startswith("s2"):
        return "classic"
    if scene.startswith("r2"):
        return "realistic"
    return "real"


def main(argv):
    if len(argv) < 2:
        sys.exit(__doc__)
    a_arg, b_arg = argv[0], argv[1]
    shown = [argv[i + 1] for i, x in enumerate(argv) if x == "--scene" and i + 1 < len(argv)]
    a, b = load(a_arg), load(b_arg)
    keys = sorted(set(a) & set(b))
    if not keys:
        sys.exit("compare_pair.py: the two runs share no (scene, method) row")
    name = lambda s: os.path.splitext(os.path.basename(s))[0] if s.endswith(".csv") else s
    na, nb = name(a_arg), name(b_arg)
    d = lambda v, k: float(v[k]["delta_1.25"])
    r = lambda v, k: float(v[k]["rms"])
    methods = sorted({m for _, m in keys})
    print(f"| method | group | scenes | {na} δ / rms | {nb} δ / rms | Δδ | {nb} better / worse |")
    print("|---|---|---|---|---|---|---|")
    for m in methods:
        ks = [k for k in keys if k[1] == m]
        for g in ["all", "classic", "realistic", "real"]:
            gk = [k for k in ks if g == "all" or group(k[0]) == g]
            if not gk:
                continue
            da, db = mean([d(a, k) for k in gk]), mean([d(b, k) for k in gk])
            better = sum(d(b, k) > d(a, k) for k in gk)
            worse = sum(d(b, k) < d(a, k) for k in gk)
            print(f"| {m} | {g} | {len(gk)} | {da:.4f} / {mean([r(a, k) for k in gk]):.3f} | "
                  f"{db:.4f} / {mean([r(b, k) for k in gk]):.3f} | {db - da:+.4f} | {better} / {worse} |")
    print()
    print(f"Rows moving by more than 0.02 (δ<1.25, {nb} − {na}):")
    print()
    for k in keys:
        diff = d(b, k) - d(a, k)
        if abs(diff) > 0.02:
            print(f"- {k[0]} {k[1]}: {d(a, k):.4f} → {d(b, k):.4f} ({diff:+.4f})")
    for s in shown:
        print()
        for k in keys:
            if k[0] == s:
                print(f"- {s} {k[1]}: δ {d(a, k):.4f} → {d(b, k):.4f}, rms {r(a, k):.3f} → {r(b, k):.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
