#!/usr/bin/env bash
# Second-order TGV against Huber-TV for keyframe depth (SPEC.md §10.4), on the validation scenes of
# tools/train_chain/validate.sh (classic renders 200000-200005 and realistic 200050-200052 at keyframe
# 20, SUN3D f0935 keyframes 15, 25, 35), `densefeat reconstruct` with every flag at its default except
# the regulariser (and --tgv-beta). `eval` has no TGV rows, hence reconstruct per keyframe.
#
#   tools/dtam/tgv_validation.sh OUT.csv [BETA...]     (default betas: 4 16)
#
# TGV_LAMBDA_RGB / TGV_LAMBDA_LEARNED set the TGV rows' --lambda (default: the kind's, as TV's);
# SKIP_BASE=1 leaves out the TV and normal-prior rows.
#
# Writes OUT.csv: scene,keyframe,features,regularizer,beta,rms,delta_1.1,delta_1.25 (full coverage).
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:?usage: $0 OUT.csv [BETA...]}
shift
[ $# -gt 0 ] && betas=("$@") || betas=(4 16)
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
. tools/train_chain/val_scenes.sh
val_scenes "$bin"
cases=()
for d in "${VAL_SCENES[@]}"; do cases+=("$d:20"); done
for k in 15 25 35; do cases+=("../shared/data/sun3d_studyroom_f0935:$k"); done
echo "scene,keyframe,features,regularizer,beta,rms,delta_1.1,delta_1.25" > "$out"
row() { # features regularizer beta dir
  python3 - "$@" <<'PY'
import json, sys
feat, reg, beta, d, scene, kf = sys.argv[1:7]
m = json.load(open(f"{d}/metrics.json"))["metrics"]
key = {"tv": "tv", "tgv": "tgv", "normals": "normals"}[reg]
r = m[key]
print(f"{scene},{kf},{feat},{reg},{beta},{r['rms']:.4f},{r['delta_1_1']:.4f},{r['delta_1_25']:.4f}")
PY
}
for c in "${cases[@]}"; do
  seq=${c%%:*}; kf=${c#*:}; scene=$(basename "$seq")
  for feat in rgb learned; do
    regs=(tv)
    [ $feat = learned ] && regs+=(normals)
    [ "${SKIP_BASE:-0}" = 1 ] && regs=()
    lam=()
    [ $feat = rgb ] && [ -n "${TGV_LAMBDA_RGB:-}" ] && lam=(--lambda "$TGV_LAMBDA_RGB")
    [ $feat = learned ] && [ -n "${TGV_LAMBDA_LEARNED:-}" ] && lam=(--lambda "$TGV_LAMBDA_LEARNED")
    for reg in ${regs[@]+"${regs[@]}"}; do
      nice -n 15 "$bin" reconstruct --sequence "$seq" --keyframe "$kf" --features $feat --regularizer $reg --out "$tmp/r" > /dev/null 2>&1
      row $feat $reg - "$tmp/r" "$scene" "$kf" >> "$out"
    done
    for b in "${betas[@]}"; do
      nice -n 15 "$bin" reconstruct --sequence "$seq" --keyframe "$kf" --features $feat --regularizer tgv --tgv-beta "$b" ${lam[@]+"${lam[@]}"} --out "$tmp/r" > /dev/null 2>&1
      row $feat tgv "$b" "$tmp/r" "$scene" "$kf" >> "$out"
    done
  done
  echo "$(date +%T) $scene $kf" >&2
done
# Means as eval's tables and validate.sh take them: each scene's keyframes averaged first (SUN3D's
# three), then the ten scenes.
python3 - "$out" <<'PY'
import csv, sys, collections
rows = list(csv.DictReader(open(sys.argv[1])))
acc = collections.defaultdict(lambda: collections.defaultdict(list))
for r in rows:
    acc[(r["features"], r["regularizer"], r["beta"])][r["scene"]].append(r)
print("| features | regulariser | β | mean rms (m) | mean δ<1.1 | mean δ<1.25 |")
print("|---|---|---|---|---|---|")
for (f, g, b), scenes in acc.items():
    per = [[sum(float(r[c]) for r in rs) / len(rs) for c in ("rms", "delta_1.1", "delta_1.25")] for rs in scenes.values()]
    m = [sum(p[i] for p in per) / len(per) for i in range(3)]
    print(f"| {f} | {g} | {b} | {m[0]:.3f} | {m[1]:.3f} | {m[2]:.3f} |")
PY
