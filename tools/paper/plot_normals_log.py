#!/usr/bin/env python3
"""Curves of a `densefeat train-normals` log.csv: training mean angle (per-100-step mean) and the
validation mean angle, against the step.

usage: plot_normals_log.py log.csv out.png [LABEL=log.csv ...]   (extra logs drawn thin, e.g. failed runs)
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def load(path):
    rows = list(csv.DictReader(open(path)))
    train = []
    for i in range(0, len(rows) - 99, 100):
        chunk = rows[i:i + 100]
        train.append((int(chunk[-1]["step"]), sum(float(r["mean_angle_deg"]) for r in chunk) / 100))
    val = [(int(r["step"]), float(r["val_mean_angle_deg"])) for r in rows if r["val_mean_angle_deg"]]
    return train, val


fig, ax = plt.subplots(figsize=(8, 4.5))
train, val = load(sys.argv[1])
ax.plot(*zip(*train), color="tab:blue", label="training batches (mean of 100 steps)")
ax.plot(*zip(*val), "o-", color="tab:orange", label="validation (the run's --val-data and synthetic validation frames)")
for extra in sys.argv[3:]:
    label, path = extra.split("=", 1)
    t, v = load(path)
    if t:
        ax.plot(*zip(*t), color="grey", lw=0.8, alpha=0.7)
    if v:
        ax.plot(*zip(*v), "x--", color="grey", lw=0.8, label=label)
ax.set_xlabel("step (4 frames each)")
ax.set_ylabel("mean angular error (degrees)")
ax.set_title("densefeat train-normals")
ax.grid(alpha=0.3)
ax.legend()
fig.tight_layout()
fig.savefig(sys.argv[2], dpi=110)
