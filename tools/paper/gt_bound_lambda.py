#!/usr/bin/env python3
"""The bound's own λ on the 101 validation scenes (issue 32 item 4, SPEC.md §10.1a).

Collects a `wide_validation.sh` run of a normal-prior method with `--normals gt --lambda-sweep
L1,L2,...` (each scene's table.csv holds the default λ's row, its lambda_sweep.csv the others) and
compares every λ with the smoothness rows of a reference csv (wide_validation's all.csv format, the
same weights): mean δ<1.25 and rms over the scenes, per group, and the scenes the bound wins.

    python3 tools/paper/gt_bound_lambda.py RUN_DIR DEFAULT_LAMBDA REFERENCE_CSV OUT_CSV [METHOD REF_METHOD]

METHOD (default learned-normals) is the swept row, REF_METHOD (default learned-tv) the reference's;
for RGB's bound: rgb-normals rgb-tv.
"""
import csv
import os
import sys
from collections import defaultdict

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "train_chain"))
from compare_pair import group, mean  # noqa: E402  (the groups of every chain comparison)


def main():
    run, default_lambda, ref_csv, out_csv = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4]
    method = sys.argv[5] if len(sys.argv) > 5 else "learned-normals"
    ref_method = sys.argv[6] if len(sys.argv) > 6 else "learned-tv"
    ref = {r["scene"]: float(r["delta_1.25"]) for r in csv.DictReader(open(ref_csv)) if r["method"] == ref_method}
    rows = defaultdict(dict)  # lambda -> scene -> (delta, rms)
    for scene in sorted(os.listdir(run)):
        d = os.path.join(run, scene)
        if not os.path.isdir(d):
            continue
        table = os.path.join(d, "table.csv")
        sweep = os.path.join(d, "lambda_sweep.csv")
        if not (os.path.exists(table) and os.path.exists(sweep)):
            sys.exit(f"gt_bound_lambda.py: {d}: table.csv or lambda_sweep.csv missing (run unfinished?)")
        for r in csv.DictReader(open(table)):
            if r["method"] == method:
                rows[default_lambda][scene] = (float(r["delta_1.25"]), float(r["rms"]))
        for r in csv.DictReader(open(sweep)):
            if r["method"] == method:
                rows[float(r["lambda"])][scene] = (float(r["delta_1.25"]), float(r["rms"]))
    with open(out_csv, "w") as f:
        f.write("lambda,scenes,mean_delta_1.25,mean_rms,classic,realistic,real,won,lost_over_0.02,worst_scene,worst_margin\n")
        for lam in sorted(rows):
            per = rows[lam]
            missing = sorted(set(ref) - set(per))
            if missing:
                sys.exit(f"gt_bound_lambda.py: λ {lam:g}: no row for {', '.join(missing)}")
            n = len(per)
            mean_d = mean([v[0] for v in per.values()])
            mean_r = mean([v[1] for v in per.values()])
            groups = defaultdict(list)
            for s, v in per.items():
                groups[group(s)].append(v[0])
            gm = {g: mean(v) for g, v in groups.items()}
            margins = {s: per[s][0] - ref[s] for s in per}
            won = sum(1 for m in margins.values() if m > 0)
            lost = sum(1 for m in margins.values() if m < -0.02)
            worst = min(margins, key=margins.get)
            f.write(f"{lam:g},{n},{mean_d:.4f},{mean_r:.4f},{gm.get('classic', float('nan')):.4f},"
                    f"{gm.get('realistic', float('nan')):.4f},{gm.get('real', float('nan')):.4f},"
                    f"{won},{lost},{worst},{margins[worst]:+.4f}\n")
            print(f"λ {lam:<5g} scenes {n}  mean δ<1.25 {mean_d:.4f}  rms {mean_r:.3f}  "
                  f"classic {gm.get('classic', 0):.4f} realistic {gm.get('realistic', 0):.4f} real {gm.get('real', 0):.4f}  "
                  f"won {won}/{n}, lost > 0.02 {lost}, worst {worst} {margins[worst]:+.4f}")
        print(f"{ref_method} (reference): mean δ<1.25 {mean(list(ref.values())):.4f} over {len(ref)} scenes")


if __name__ == "__main__":
    main()
