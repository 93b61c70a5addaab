#!/usr/bin/env bash
# Issue 32's bound on validation (SPEC.md §3a, §10.2): per validation scene, smoothness (rgb-tv,
# learned-tv) against the normal prior with ground-truth normals (rgb-normals, learned-normals,
# `--normals gt`), over λ 30, 100, 300 (`eval --lambda-sweep`), every other flag at its default.
# BIN picks the binary (to compare two ground-truth normal stencils on the same scenes).
#
#   BIN=path/to/densefeat tools/paper/gt_bound_val.sh TAG
#
# Writes runs/val/gtbound_TAG/<scene>/ and runs/val/gtbound_TAG/all.csv
# (scene, method, lambda, rms, delta_1.25, abs_rel, coverage).
set -euo pipefail
cd "$(dirname "$0")/../.."

tag=$1
bin=${BIN:-target/release/densefeat}
weights=fixtures/weights/featurenet_trained_b1s2.safetensors
root=runs/val/gtbound_$tag
mkdir -p "$root"
scenes=()
for seed in 200000 200001 200002 200003 200004 200005; do
  d=runs/val/s$seed
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 --out "$d" --quiet && touch "$d/.done"; }
  scenes+=("$d:20:10:20")
done
for seed in 200050 200051 200052; do
  d=runs/val/r$seed
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 --style real --out "$d" --quiet && touch "$d/.done"; }
  scenes+=("$d:20:10:20")
done
scenes+=("../shared/data/sun3d_studyroom_f0935:15:10:35")
all=$root/all.csv
echo "scene,method,lambda,rms,delta_1.25,abs_rel,coverage" > "$all"
for sk in "${scenes[@]}"; do
  seq=${sk%%:*}; kfs=${sk#*:}; scene=$(basename "$seq")
  out=$root/$scene
  "$bin" eval --sequence "$seq" --keyframes "$kfs" --methods ${METHODS:-rgb-tv,learned-tv,rgb-normals,learned-normals} \
    --normals gt --weights "$weights" --lambda-sweep ${LAMBDAS:-30,100,300} --out "$out" > "$out.log" 2>&1
  awk -F, -v scene="$scene" 'NR > 1 && $1 !~ /@/ { print scene "," $0 }' "$out/lambda_sweep.csv" >> "$all"
  echo "$scene done"
done
