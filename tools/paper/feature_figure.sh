#!/usr/bin/env bash
# The paper's feature comparison (its Fig. 4 and supplementary figures; issue 32 item 2) on this
# project's test scenes: winner-take-all depth from the cost volume of each feature type (rgb,
# learned, b1 = block 1 alone, dsift, patch7) with 1 live frame and with 30, every other flag at its
# default, one picture grid per example (eval --figure) and rms / δ<1.1 / δ<1.25 per method. Test
# scenes are run once per issue, at the end: this script is that run. The examples are fixed here,
# before any result: SUN3D f3160 keyframe 25, TUM fr1_rpy keyframe 60, classic render 5 and
# realistic render 13 at keyframe 20 (test_scenes.sh renders them).
#
#   tools/paper/feature_figure.sh TAG
#   METHODS=learned-wta,b1-wta tools/paper/feature_figure.sh TAG   # only those methods (e.g. new weights)
#
# Writes runs/test/TAG/<scene>_w1 and _w30 (eval's folders, figure_kfNNNNN.png) and prints the table.
set -euo pipefail
cd "$(dirname "$0")/../.."

tag=${1:-features}
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
root=runs/test/$tag
mkdir -p "$root" runs/test/scenes
for seed in 5; do
  d=runs/test/scenes/s$seed
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 --out "$d" --quiet && touch "$d/.done"; }
done
for seed in 13; do
  d=runs/test/scenes/r$seed
  [ -f "$d/.done" ] || { "$bin" synth --seed $seed --frames 40 --size 320x240 --style real --out "$d" --quiet && touch "$d/.done"; }
done
examples=("../shared/data/sun3d_studyroom_f3160:25" "../shared/data/tum_fr1_rpy:60"
          "runs/test/scenes/s5:20" "runs/test/scenes/r13:20")
csv=$root/all.csv
echo "scene,live_frames,method,rms,delta_1.1,delta_1.25" > "$csv"
for ex in "${examples[@]}"; do
  seq=${ex%%:*}; kf=${ex#*:}; scene=$(basename "$seq")
  for w in "0,1:1" "15,15:30"; do
    window=${w%%:*}; n=${w#*:}
    out=$root/${scene}_w$n
    echo "$(date -u +%T) $scene, $n live frame(s)"
    "$bin" eval --sequence "$seq" --keyframes "$kf:1:$kf" --window "$window" \
      --methods "${METHODS:-rgb-wta,learned-wta,b1-wta,dsift-wta,patch7-wta}" --figure --out "$out" > "$out.log" 2>&1
    python3 - "$out/table.csv" "$scene" "$n" >> "$csv" <<'PY'
import csv, sys
for r in csv.DictReader(open(sys.argv[1])):
    if "@" in r["method"]:
        continue
    print(f"{sys.argv[2]},{sys.argv[3]},{r['method']},{r['rms']},{r['delta_1.1']},{r['delta_1.25']}")
PY
  done
done
python3 - "$csv" <<'PY'
import csv, sys
from collections import OrderedDict
rows = list(csv.DictReader(open(sys.argv[1])))
methods = list(OrderedDict.fromkeys(r["method"] for r in rows))
print("| example | live frames | " + " | ".join(methods) + " |")
print("|---|---|" + "---|" * len(methods))
keys = list(OrderedDict.fromkeys((r["scene"], r["live_frames"]) for r in rows))
val = {(r["scene"], r["live_frames"], r["method"]): r for r in rows}
for s, n in keys:
    cells = []
    for m in methods:
        r = val.get((s, n, m))
        cells.append(f"{float(r['rms']):.2f} / {float(r['delta_1.1']):.3f} / {float(r['delta_1.25']):.3f}" if r else "")
    print(f"| {s} | {n} | " + " | ".join(cells) + " |")
print()
print("Cells: rms (m) / δ<1.1 / δ<1.25 of the winner-take-all depth.")
PY
