#!/usr/bin/env bash
# The learned winner-take-all depth on blank pixels, on classic-style renders of training seeds (the
# scenes chain mxso trained on: `--synthetic-style mixed` renders even seeds classic) and on the six
# classic validation scenes (docs/table1/README.md, "The blank wall on the training scenes").
#
#   tools/paper/blank_categories.sh [TAG=WEIGHTS ...]   # default: mf4so and mxso
#
# Renders runs/blank/SEED (40 frames, 320x240, classic: as validation renders its scenes), evaluates
# learned-wta at keyframe 20 with each weights file (runs/blank/e_TAG_SCENE/), then prints
# tools/paper/blank_categories.py's table for every run.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
[ $# -gt 0 ] || set -- mf4so=fixtures/weights/featurenet_trained_mf4so.safetensors \
  mxso=docs/training/chain_mxso/weights.safetensors
out=runs/blank
mkdir -p $out
scenes=()
for s in 100000 100002 100004 100006 100008 100010 100012 100014; do
  [ -d $out/c$s ] || $bin synth --seed $s --frames 40 --size 320x240 --style classic --out $out/c$s > /dev/null
  scenes+=($out/c$s)
done
for s in 200000 200001 200002 200003 200004 200005; do
  [ -d $out/s$s ] || $bin synth --seed $s --frames 40 --size 320x240 --style classic --out $out/s$s > /dev/null
  scenes+=($out/s$s)
done
args=()
for tw in "$@"; do
  tag=${tw%%=*}; w=${tw#*=}
  for d in "${scenes[@]}"; do
    e=$out/e_${tag}_$(basename $d)
    [ -f $e/table.csv ] || nice $bin eval --sequence $d --keyframes 20:10:20 --methods learned-wta \
      --weights $w --save-depth --out $e > $e.log 2>&1
    args+=("$d:$e")
  done
done
python3 tools/paper/blank_categories.py "${args[@]}"
