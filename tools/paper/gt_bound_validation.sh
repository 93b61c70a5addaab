#!/usr/bin/env bash
# The ground-truth-normal bound on the ten validation scenes of validate.sh, every flag at its default
# (docs/table1/README.md).
#
#   tools/paper/gt_bound_validation.sh            # or: TAG=NAME tools/paper/gt_bound_validation.sh
#   TAG=NAME WEIGHTS=FILE tools/paper/gt_bound_validation.sh   # other feature weights (a chain's)
#
# Renders the scenes into runs/val/ when missing; writes runs/gtfit/SCENE/ (eval's outputs) and
# docs/table1/gt_bound/fit_validation.csv (their table.csv rows); with TAG=NAME runs/gtfit_NAME/ and
# docs/table1/gt_bound/fit_validation_NAME.csv, so an earlier binary's table stays.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
runs=runs/gtfit${TAG:+_$TAG}
mkdir -p $runs
. tools/train_chain/val_scenes.sh
val_scenes "$bin"
scenes=()
for d in "${VAL_SCENES[@]}"; do scenes+=("$d:20:10:20"); done
scenes+=("../shared/data/sun3d_studyroom_f0935:15:10:35")
for sk in "${scenes[@]}"; do
  seq=${sk%%:*}; kfs=${sk#*:}; scene=$(basename $seq)
  nice $bin eval --sequence $seq --keyframes $kfs --methods rgb-tv,rgb-normals,learned-tv,learned-normals --normals gt ${WEIGHTS:+--weights $WEIGHTS} --out $runs/$scene > $runs/$scene.log 2>&1
done
touch $runs/.done
out=docs/table1/gt_bound/fit_validation${TAG:+_$TAG}.csv
echo "scene,method,rms,log_rms,abs_rel,sq_rel,delta_1.1,delta_1.25,delta_1.25^2,delta_1.25^3,coverage" > $out
for d in $runs/*/; do
  awk -F, -v s="$(basename "$d")" 'NR > 1 && $1 !~ /@/ { print s "," $0 }' "$d/table.csv" >> $out
done
