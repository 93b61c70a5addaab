"""Plots the chain's full-mapper validation (tools/train_chain/validate.sh) and names the best step.

usage: plot_validation.py validation.csv validation.png best.txt STEP

Per evaluated step, the mean over the validation scenes of δ<1.25 for learned-WTA and learned-TV
(lines) against RGB-WTA and RGB-TV (horizontal: they do not depend on the weights). best.txt gets the
step with the highest mean learned-TV δ<1.25 over the scenes evaluated at every step.
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    path, png, best_path = sys.argv[1:4]
    rows = list(csv.DictReader(open(path)))
    by = defaultdict(dict)  # (method, step) -> scene -> (delta, rms)
    for r in rows:
        by[(r["method"], int(r["step"]))][r["scene"]] = (float(r["delta_1.25"]), float(r["rms"]))
    steps = sorted({s for (m, s) in by if m.startswith("learned")})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, k, label in [(axes[0], 0, "mean δ<1.25 (higher is better)"), (axes[1], 1, "mean rms, m (lower is better)")]:
        for m, style in [("learned-wta", "o--"), ("learned-tv", "o-")]:
            ys = [sum(v[k] for v in by[(m, s)].values()) / len(by[(m, s)]) for s in steps]
            ax.plot(steps, ys, style, label=m)
        for m, style in [("rgb-wta", ":"), ("rgb-tv", "-.")]:
            vals = [v for (mm, s), d in by.items() if mm == m for v in d.values()]
            if vals:
                ax.axhline(sum(v[k] for v in vals) / len(vals), linestyle=style[0] if style != "-." else "-.", color="grey", label=m)
        ax.set_xlabel("optimiser step (4 pairs each)")
        ax.set_title(label)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("Chain validation: densefeat eval, default flags, validation scenes (SPEC §3a)")
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    scores = {s: sum(v[0] for v in by[("learned-tv", s)].values()) / len(by[("learned-tv", s)]) for s in steps}
    best = max(scores, key=lambda s: (scores[s], -s))
    open(best_path, "w").write(f"{best}\n")


if __name__ == "__main__":
    main()
