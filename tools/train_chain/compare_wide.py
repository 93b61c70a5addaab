#!/usr/bin/env python3
"""Side by side: wide_validation.sh runs (runs/valwide/TAG/all.csv) of several weights against the
shared RGB rows. Per tag: mean δ<1.25 and rms of learned-TV and learned-WTA over all scenes and per
renderer style, the margin over RGB-TV, and the scenes learned-TV loses to RGB-TV by more than 0.02
(issue 30's acceptance, on validation).

    python3 tools/train_chain/compare_wide.py TAG|FILE.csv [TAG|FILE.csv...]

A TAG reads runs/valwide/TAG/all.csv; a FILE.csv (e.g. docs/training/wide_validation/mf4l.csv) is read
as it is and named by its stem.
"""
import os
import csv
import sys


def load(tag):
    path = tag if tag.endswith(".csv") else f"runs/valwide/{tag}/all.csv"
    rows = list(csv.DictReader(open(path)))
    return {(r["scene"], r["method"]): r for r in rows}


def mean(xs):
    return sum(xs) / len(xs) if xs else float("nan")


args = sys.argv[1:]
tags = [os.path.splitext(os.path.basename(a))[0] if a.endswith(".csv") else a for a in args]
data = {t: load(a) for t, a in zip(tags, args)}
scenes = sorted({s for t in tags for (s, _) in data[t]})
groups = {
    "classic": [s for s in scenes if s.startswith("s2")],
    "realistic": [s for s in scenes if s.startswith("r2")],
    "real": [s for s in scenes if not (s.startswith("s2") or s.startswith("r2"))],
    "all": scenes,
}
d = lambda v, s, m: float(v[(s, m)]["delta_1.25"])
r = lambda v, s, m: float(v[(s, m)]["rms"])
v0 = data[tags[0]]
print("| weights | group | scenes | RGB-TV δ / rms | learned-TV δ / rms | learned-WTA δ | margin | lost by > 0.02 |")
print("|---|---|---|---|---|---|---|---|")
for t in tags:
    v = data[t]
    for g, ss in groups.items():
        ss = [s for s in ss if (s, "learned-tv") in v and (s, "rgb-tv") in v]
        if not ss:
            continue
        rgb = mean([d(v, s, "rgb-tv") for s in ss])
        lt = mean([d(v, s, "learned-tv") for s in ss])
        lost = [s for s in ss if d(v, s, "learned-tv") - d(v, s, "rgb-tv") < -0.02]
        print(f"| {t} | {g} | {len(ss)} | {rgb:.4f} / {mean([r(v, s, 'rgb-tv') for s in ss]):.3f} | "
              f"{lt:.4f} / {mean([r(v, s, 'learned-tv') for s in ss]):.3f} | "
              f"{mean([d(v, s, 'learned-wta') for s in ss]):.4f} | {lt - rgb:+.4f} | {len(lost)} |")
print()
print("Scenes lost by more than 0.02 (learned-TV − RGB-TV δ<1.25) under any of the weights:")
print()
print("| scene | RGB-TV | " + " | ".join(tags) + " |")
print("|---|---|" + "---|" * len(tags))
for s in scenes:
    margins = [d(data[t], s, "learned-tv") - d(data[t], s, "rgb-tv") for t in tags if (s, "learned-tv") in data[t]]
    if margins and min(margins) < -0.02:
        cells = [f"{d(data[t], s, 'learned-tv'):.3f} ({d(data[t], s, 'learned-tv') - d(data[t], s, 'rgb-tv'):+.3f})"
                 if (s, "learned-tv") in data[t] else "" for t in tags]
        print(f"| {s} | {d(v0, s, 'rgb-tv'):.3f} | " + " | ".join(cells) + " |")
