#!/usr/bin/env bash
# `densefeat map` on the test scenes of SPEC.md §3a, run once per issue at the end (issue 31). Every
# flag at its default plus the flags given. The scene list is fixed here, before any result:
#   render: classic seeds 2-11 and realistic seeds 12-14 (40 frames, 320x240), the renders of
#           tools/train_chain/test_scenes.sh (made here if missing)
#   real:   SUN3D f3160 (all 50 frames, 640x480), TUM fr1_rpy (all 120 frames, 640x480)
# Prints F-score at 2 / 5 / 10 cm (precision / recall at 5 cm) per scene and the means.
#
#   tools/map/test_scenes.sh TAG [map flags...]
#
# Writes runs/maptest/TAG/<scene>/ (map's folders) and runs/maptest/TAG/fscore.csv (the loop of
# tools/map/validate.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."

bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
mkdir -p runs/test/scenes
scenes=""
for seed in 2 3 4 5 6 7 8 9 10 11 12 13 14; do
  if [ $seed -ge 12 ]; then d=runs/test/scenes/r$seed; style=(--style real); else d=runs/test/scenes/s$seed; style=(); fi
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 "${style[@]}" --out "$d" --quiet && touch "$d/.done"; }
  scenes+="$d "
done
scenes+="../shared/data/sun3d_studyroom_f3160 ../shared/data/tum_fr1_rpy"
ROOT=runs/maptest SCENES="$scenes" BIN="$bin" exec tools/map/validate.sh "$@"
