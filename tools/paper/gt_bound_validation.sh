#!/usr/bin/env bash
# Usage: tools/paper/gt_bound_validation.sh (from the project root; the scenes of tools/train_chain/validate.sh in runs/val/).
# Writes runs/gtfit/SCENE/ (eval's outputs) and docs/table1/gt_bound/fit_validation.csv (their table.csv rows).
# The ground-truth-normal bound on the ten validation scenes of validate.sh, every flag at its default.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=target/release/densefeat
for sk in runs/val/r200050:20:10:20 runs/val/r200051:20:10:20 runs/val/r200052:20:10:20 runs/val/s200000:20:10:20 runs/val/s200001:20:10:20 runs/val/s200002:20:10:20 runs/val/s200003:20:10:20 runs/val/s200004:20:10:20 runs/val/s200005:20:10:20 ../shared/data/sun3d_studyroom_f0935:15:10:35; do
  seq=${sk%%:*}; kfs=${sk#*:}; scene=$(basename $seq)
  nice $bin eval --sequence $seq --keyframes $kfs --methods rgb-tv,rgb-normals,learned-tv,learned-normals --normals gt --out runs/gtfit/$scene > runs/gtfit/$scene.log 2>&1
done
touch runs/gtfit/.done
out=docs/table1/gt_bound/fit_validation.csv
echo "scene,method,rms,log_rms,abs_rel,sq_rel,delta_1.1,delta_1.25,delta_1.25^2,delta_1.25^3,coverage" > $out
for d in runs/gtfit/*/; do
  awk -F, -v s="$(basename "$d")" 'NR > 1 && $1 !~ /@/ { print s "," $0 }' "$d/table.csv" >> $out
done
