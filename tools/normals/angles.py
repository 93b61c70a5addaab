#!/usr/bin/env python3
"""Collect the predictor's angular error (eval's normals_error.csv) of a wide-validation run.

    python3 tools/normals/angles.py runs/valwide/TAG OUT.csv [--compare OLD.csv]

Writes scene,keyframe,normals_mean_angle_deg,normals_median_angle_deg,pixels (the format of
docs/training/wide_validation/normals_*_angles.csv) and prints the mean of the scenes' keyframe means
per group (classic renders s2000xx, realistic r2000xx, the real room), and with --compare the same for
another such file over the keyframes both have.
"""
import argparse
import csv
import os
from collections import defaultdict


def read(path):
    rows = {}
    with open(path) as f:
        for r in csv.DictReader(f):
            rows[(r["scene"], r["keyframe"])] = float(r["normals_mean_angle_deg"])
    return rows


def groups(rows, keys):
    per_scene = defaultdict(list)
    for k in keys:
        per_scene[k[0]].append(rows[k])
    g = defaultdict(list)
    for scene, v in per_scene.items():
        name = "classic" if scene.startswith("s2") else "realistic" if scene.startswith("r2") else "real"
        g[name].append(sum(v) / len(v))
        g["all"].append(sum(v) / len(v))
    return {k: (sum(v) / len(v), len(v)) for k, v in g.items()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("out")
    ap.add_argument("--compare")
    a = ap.parse_args()
    out = []
    for scene in sorted(os.listdir(a.run)):
        p = os.path.join(a.run, scene, "normals_error.csv")
        if os.path.isfile(p):
            with open(p) as f:
                for r in csv.DictReader(f):
                    out.append([scene, r["keyframe"], r["normals_mean_angle_deg"], r["normals_median_angle_deg"], r["pixels"]])
    with open(a.out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "keyframe", "normals_mean_angle_deg", "normals_median_angle_deg", "pixels"])
        w.writerows(out)
    new = read(a.out)
    sets = [("this run", new, sorted(new))]
    if a.compare:
        old = read(a.compare)
        both = sorted(set(new) & set(old))
        sets = [("this run", new, both), (os.path.basename(a.compare), old, both)]
    for name, rows, keys in sets:
        g = groups(rows, keys)
        print(name + ": " + ", ".join(f"{k} {v[0]:.1f}° ({v[1]})" for k, v in sorted(g.items())))


if __name__ == "__main__":
    main()
