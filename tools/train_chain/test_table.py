#!/usr/bin/env python3
"""Markdown tables of a test_scenes.sh run (issue 30's acceptance): per scene δ<1.25 / rms of every
method, means (real, renders, all), the eight metrics' means, and the acceptance checks
(learned-TV and learned-normals vs RGB-TV: mean δ<1.25 margin >= 0.03, lower mean rms, no scene lost by > 0.02)."""
import csv
import sys
from collections import OrderedDict

rows = list(csv.DictReader(open(sys.argv[1])))
methods = list(OrderedDict.fromkeys(r["method"] for r in rows))
scenes = list(OrderedDict.fromkeys(r["scene"] for r in rows))
val = {(r["scene"], r["method"]): r for r in rows}
real = [s for s in scenes if not (s[0] in "sr" and s[1:].isdigit())]
renders = [s for s in scenes if s not in real]
metrics = ["rms", "log_rms", "abs_rel", "sq_rel", "delta_1.1", "delta_1.25", "delta_1.25^2", "delta_1.25^3"]


def mean(group, m, key):
    xs = [float(val[(s, m)][key]) for s in group if (s, m) in val]
    return sum(xs) / len(xs) if xs else float("nan")


print("| scene | " + " | ".join(methods) + " |")
print("|---|" + "---|" * len(methods))
for s in scenes:
    cells = [f"{float(val[(s, m)]['delta_1.25']):.3f} / {float(val[(s, m)]['rms']):.2f}" if (s, m) in val else "" for m in methods]
    print(f"| {s} | " + " | ".join(cells) + " |")
for name, group in (("mean, real", real), ("mean, renders", renders), ("mean, all", scenes)):
    cells = [f"{mean(group, m, 'delta_1.25'):.3f} / {mean(group, m, 'rms'):.2f}" for m in methods]
    print(f"| **{name}** ({len(group)}) | " + " | ".join(cells) + " |")
print()
print("Means over all scenes, the eight metrics of SPEC §3:")
print()
print("| method | " + " | ".join(metrics) + " |")
print("|---|" + "---|" * len(metrics))
for m in methods:
    print(f"| {m} | " + " | ".join(f"{mean(scenes, m, k):.4f}" for k in metrics) + " |")
# Issue 30's checks against RGB-TV for learned-TV (the paper's method) and learned-normals (the learned
# features' default regulariser since 2026-12-04, SPEC.md §10.1b).
for lm, label in (("learned-tv", "learned-TV"), ("learned-normals", "learned-normals")):
    if lm not in methods or "rgb-tv" not in methods:
        continue
    print()
    d = mean(scenes, lm, "delta_1.25") - mean(scenes, "rgb-tv", "delta_1.25")
    drms = mean(scenes, lm, "rms") - mean(scenes, "rgb-tv", "rms")
    worst = min(scenes, key=lambda s: float(val[(s, lm)]["delta_1.25"]) - float(val[(s, "rgb-tv")]["delta_1.25"]))
    wd = float(val[(worst, lm)]["delta_1.25"]) - float(val[(worst, "rgb-tv")]["delta_1.25"])
    print(f"{label} − RGB-TV: mean δ<1.25 {d:+.3f} (target ≥ +0.03: {'met' if d >= 0.03 else 'NOT met'}), "
          f"mean rms {drms:+.3f} m ({'lower' if drms < 0 else 'NOT lower'}), "
          f"worst scene {worst} {wd:+.3f} (target ≥ −0.02: {'met' if wd >= -0.02 else 'NOT met'})")
