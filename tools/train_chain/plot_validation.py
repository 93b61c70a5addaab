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
    fig, axes = plt.subplots(1, 3, figsize=(16, 4))
    real = "sun3d_studyroom_f0935"
    panels = [
        (axes[0], 0, None, "mean δ<1.25 over all scenes (higher is better)"),
        (axes[1], 1, None, "mean rms over all scenes, m (lower is better)"),
        (axes[2], 0, real, "δ<1.25 on the real scene, SUN3D f0935"),
    ]
    for ax, k, only, label in panels:
        pick = lambda d: [v[k] for sc, v in d.items() if only is None or sc == only]  # noqa: E731
        for m, style in [("learned-wta", "o--"), ("learned-tv", "o-")]:
            ys = [sum(pick(by[(m, s)])) / max(1, len(pick(by[(m, s)]))) for s in steps]
            ax.plot(steps, ys, style, label=m)
        for m, style in [("rgb-wta", ":"), ("rgb-tv", "-.")]:
            vals = [v for (mm, s), d in by.items() if mm == m for v in pick(d)]
            if vals:
                ax.axhline(sum(vals) / len(vals), linestyle=style, color="grey", label=m)
        ax.set_xlabel("optimiser step")
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
