#!/usr/bin/env python3
"""The paper's Table 1 from two test_scenes.sh runs (tools/paper/table1.sh): BUILTIN (rgb-tv,
learned-tv, rgb-normals, learned-normals with the built-in predictor's normals, and its
normals_error.csv per scene) and GT (the normal-prior rows with ground-truth normals, the bound).
Prints per scene δ<1.25 / rms of each variant, the means of the eight metrics (SPEC §3), the
predictor's angular error per scene, and issue 32's check: with ground-truth normals the prior beats
smoothness (δ<1.25) on every test scene, for each feature kind."""
import csv
import os
import sys
from collections import OrderedDict

builtin, gt = sys.argv[1], sys.argv[2]
rows = []
for r in csv.DictReader(open(os.path.join(builtin, "all.csv"))):
    rows.append(r)
for r in csv.DictReader(open(os.path.join(gt, "all.csv"))):
    r = dict(r)
    r["method"] = r["method"] + " (gt normals)"
    rows.append(r)
order = ["rgb-tv", "learned-tv", "rgb-normals", "learned-normals",
         "rgb-normals (gt normals)", "learned-normals (gt normals)"]
names = {"rgb-tv": "P.E.+S", "learned-tv": "L.F.E.+S", "rgb-normals": "P.E.+normals",
         "learned-normals": "L.F.E.+normals", "rgb-normals (gt normals)": "P.E.+GT normals (bound)",
         "learned-normals (gt normals)": "L.F.E.+GT normals (bound)"}
methods = [m for m in order if any(r["method"] == m for r in rows)]
scenes = list(OrderedDict.fromkeys(r["scene"] for r in rows))
val = {(r["scene"], r["method"]): r for r in rows}
metrics = ["rms", "log_rms", "abs_rel", "sq_rel", "delta_1.1", "delta_1.25", "delta_1.25^2", "delta_1.25^3"]


def mean(m, key):
    xs = [float(val[(s, m)][key]) for s in scenes if (s, m) in val]
    return sum(xs) / len(xs) if xs else float("nan")


print("Means over the %d test scenes, the eight metrics of SPEC §3 (rms, log rms in m / log m):" % len(scenes))
print()
print("| variant | " + " | ".join(metrics) + " |")
print("|---|" + "---|" * len(metrics))
for m in methods:
    print(f"| {names[m]} (`{m.split(' ')[0]}`) | " + " | ".join(f"{mean(m, k):.3f}" for k in metrics) + " |")
print()
print("Per scene, δ<1.25 / rms (m):")
print()
print("| scene | " + " | ".join(names[m] for m in methods) + " | predictor's mean angular error |")
print("|---|" + "---|" * (len(methods) + 1))
errors = {}
for s in scenes:
    p = os.path.join(builtin, s, "normals_error.csv")
    if os.path.exists(p):
        er = list(csv.DictReader(open(p)))
        if er:
            errors[s] = sum(float(e["normals_mean_angle_deg"]) for e in er) / len(er)
for s in scenes:
    cells = [f"{float(val[(s, m)]['delta_1.25']):.3f} / {float(val[(s, m)]['rms']):.2f}" if (s, m) in val else ""
             for m in methods]
    err = f"{errors[s]:.1f}°" if s in errors else ""
    print(f"| {s} | " + " | ".join(cells) + f" | {err} |")
if errors:
    print()
    print(f"Predictor's angular error, mean over the scenes' keyframe means: {sum(errors.values()) / len(errors):.1f}°")
print()
for kind in ("rgb", "learned"):
    tv, bound = f"{kind}-tv", f"{kind}-normals (gt normals)"
    if tv not in methods or bound not in methods:
        continue
    lost = [(s, float(val[(s, bound)]["delta_1.25"]) - float(val[(s, tv)]["delta_1.25"]))
            for s in scenes if (s, bound) in val and (s, tv) in val]
    bad = [(s, d) for s, d in lost if d <= 0]
    print(f"{kind}: ground-truth normals beat smoothness (δ<1.25) on {len(lost) - len(bad)} of {len(lost)} "
          f"test scenes" + ("" if not bad else "; not on " + ", ".join(f"{s} ({d:+.3f})" for s, d in bad)))
