#!/usr/bin/env bash
# λ per feature type, chosen on validation (issue 30 item 4, SPEC.md §13.10): `densefeat eval
# --lambda-sweep` on validate.sh's ten validation scenes for RGB-TV and learned-TV with WEIGHTS,
# every other flag at its default; prints the mean δ<1.25 and rms per (method, λ) and writes them
# to docs/training/chain_NAME/lambda_sweep_METHODS.csv.
#
#   tools/train_chain/lambda_sweep.sh NAME WEIGHTS [LAMBDAS]
#
# METHODS=rgb-tv (or learned-tv) limits it to one feature type (RGB does not depend on WEIGHTS);
# the csv then gets that type's rows. EXTRA adds eval flags (e.g. EXTRA="--normals gt" for the
# -normals methods), OUTDIR replaces docs/training/chain_NAME as the csv's folder.
set -euo pipefail
cd "$(dirname "$0")/../.."

name=$1
weights=$2
lambdas=${3:-30,100,300,1000,3000}
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
root=runs/val/sweep_${name}_${METHODS:-all}
mkdir -p "$root"
. tools/train_chain/val_scenes.sh
val_scenes "$bin"
scenes=()
for d in "${VAL_SCENES[@]}"; do scenes+=("$d:20:10:20"); done
scenes+=("../shared/data/sun3d_studyroom_f0935:15:10:35")
all=$root/all.csv
echo "scene,method,lambda,rms,delta_1.25,abs_rel,coverage" > "$all"
for sk in "${scenes[@]}"; do
  seq=${sk%%:*}; kfs=${sk#*:}; scene=$(basename "$seq")
  [ -d "$seq" ] || { echo "$seq missing: run tools/train_chain/validate.sh first" >&2; exit 1; }
  out=$root/$scene
  nice -n 10 "$bin" eval --sequence "$seq" --keyframes "$kfs" --methods "${METHODS:-rgb-tv,learned-tv}" \
    --weights "$weights" --lambda-sweep "$lambdas" ${EXTRA:-} --out "$out" > "$out.log" 2>&1
  awk -F, -v scene="$scene" 'NR > 1 && $1 !~ /@/ { print scene "," $0 }' "$out/lambda_sweep.csv" >> "$all"
done
outdir=${OUTDIR:-docs/training/chain_$name}
mkdir -p "$outdir"
python3 - "$all" "$outdir/lambda_sweep_${METHODS:-all}.csv" <<'PY'
import csv, sys
from collections import defaultdict
acc = defaultdict(list)
for r in csv.DictReader(open(sys.argv[1])):
    acc[(r["method"], float(r["lambda"]))].append((float(r["delta_1.25"]), float(r["rms"])))
with open(sys.argv[2], "w") as f:
    f.write("method,lambda,scenes,mean_delta_1.25,mean_rms\n")
    for (m, l), v in sorted(acc.items()):
        d = sum(x for x, _ in v) / len(v); r = sum(y for _, y in v) / len(v)
        f.write(f"{m},{l:g},{len(v)},{d:.4f},{r:.4f}\n")
        print(f"{m:12s} λ={l:<6g} scenes {len(v):2d}  mean δ<1.25 {d:.4f}  rms {r:.3f}")
PY
