#!/usr/bin/env bash
# Issue 30's honest table, run once per issue at the end (SPEC.md §3a, §13.10): `densefeat eval`
# with every flag at its default except the weights (and, where validation chose one, the learned
# λ) on the test scenes, for eval's default methods (RGB-WTA, RGB-TV, learned-WTA, learned-TV and,
# since 2026-12-04, learned-normals). The scene list is fixed
# here, before any test result exists:
#   real:   SUN3D f3160 keyframes 15, 25, 35; TUM fr1_rpy keyframes 30, 60, 90
#   render: classic seeds 2-11 and realistic seeds 12-14 (40 frames, 320x240, keyframe 20)
#
#   tools/train_chain/test_scenes.sh TAG WEIGHTS [extra eval flags...]
#
# Writes runs/test/TAG/<scene>/ (eval's folders) and runs/test/TAG/all.csv (scene, method and the
# eight metrics of SPEC §3 plus coverage, full-coverage rows only).
set -euo pipefail
cd "$(dirname "$0")/../.."

tag=$1
weights=$2
shift 2
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
root=runs/test/$tag
mkdir -p "$root" runs/test/scenes

scenes=()
for seed in 2 3 4 5 6 7 8 9 10 11; do
  d=runs/test/scenes/s$seed
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 --out "$d" --quiet && touch "$d/.done"; }
  scenes+=("$d:20:10:20")
done
for seed in 12 13 14; do
  d=runs/test/scenes/r$seed
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 --style real --out "$d" --quiet && touch "$d/.done"; }
  scenes+=("$d:20:10:20")
done
scenes+=("../shared/data/sun3d_studyroom_f3160:15:10:35" "../shared/data/tum_fr1_rpy:30:30:90")

csv=$root/all.csv
echo "scene,method,rms,log_rms,abs_rel,sq_rel,delta_1.1,delta_1.25,delta_1.25^2,delta_1.25^3,coverage" > "$csv"
for sk in "${scenes[@]}"; do
  seq=${sk%%:*}; kfs=${sk#*:}; scene=$(basename "$seq")
  out=$root/$scene
  echo "$(date -u +%T) $scene"
  "$bin" eval --sequence "$seq" --keyframes "$kfs" --weights "$weights" --out "$out" "$@" > "$out.log" 2>&1
  awk -F, -v scene="$scene" 'NR > 1 && $1 !~ /@/ { print scene "," $0 }' "$out/table.csv" >> "$csv"
done
python3 tools/train_chain/test_table.py "$csv"
