#!/usr/bin/env bash
# `densefeat map` on every validation scene of SPEC.md §3a (issue 31): SUN3D f0935 and the 100
# rendered rooms of seeds 200000-200099 (classic 200000-200049, realistic 200050-200099; 40 frames at
# 320x240, rendered as tools/train_chain/wide_validation.sh renders them, into the same folders).
# validate.sh's 8 scenes decide little: a map default moves each by ±0.005 and the rule "loses no
# scene" then rests on noise. So map defaults are checked here too: mean F-score at 5 cm over the
# 101 scenes, and how many scenes gain or lose.
#
#   tools/map/wide_validation.sh TAG [map flags...]
#   tools/map/wide_validation.sh --compare A B    (each a TAG or an fscore.csv file)
#
# Writes runs/mapwide/TAG/<scene>/ and runs/mapwide/TAG/fscore.csv (validate.sh's columns). About
# 20 minutes per TAG on 2 cores. SEEDS="200000 200050" limits the renders.
set -euo pipefail
cd "$(dirname "$0")/../.."

if [ "${1:-}" = "--compare" ]; then
  [ $# -eq 3 ] || { echo "usage: $0 --compare A B (each a TAG of runs/mapwide or an fscore.csv)" >&2; exit 2; }
  csv() { if [ -f "$1" ]; then echo "$1"; else echo "runs/mapwide/$1/fscore.csv"; fi; }
  for f in "$(csv "$2")" "$(csv "$3")"; do [ -f "$f" ] || { echo "$0 --compare: $f: no such file (run the TAG first)" >&2; exit 2; }; done
  exec python3 - "$(csv "$2")" "$(csv "$3")" <<'PY'
import csv, sys
a = {r["scene"]: r for r in csv.DictReader(open(sys.argv[1]))}
b = {r["scene"]: r for r in csv.DictReader(open(sys.argv[2]))}
common = sorted(set(a) & set(b))
missing = sorted(set(a) ^ set(b))
if missing:
    print(f"scenes in only one run (left out): {' '.join(missing)}")
def summary(name, scenes):
    if not scenes:
        return
    d = [float(b[s]["f5"]) - float(a[s]["f5"]) for s in scenes]
    ma = sum(float(a[s]["f5"]) for s in scenes) / len(scenes)
    mb = sum(float(b[s]["f5"]) for s in scenes) / len(scenes)
    worst = min(zip(d, scenes))
    print(f"| {name} ({len(scenes)}) | {ma:.4f} | {mb:.4f} | {mb - ma:+.4f} | "
          f"{sum(x > 0 for x in d)} / {sum(x < 0 for x in d)} | {worst[0]:+.4f} ({worst[1]}) |")
name = lambda p: p.split("/")[-2] if p.endswith("/fscore.csv") else p.split("/")[-1].removesuffix(".csv")
print(f"| scenes | F @ 5 cm, {name(sys.argv[1])} | F @ 5 cm, {name(sys.argv[2])} | change | better / worse | largest loss |")
print("|---|---|---|---|---|---|")
summary("classic renders", [s for s in common if s.startswith("s2")])
summary("realistic renders", [s for s in common if s.startswith("r2")])
summary("real room", [s for s in common if s.startswith("sun3d")])
summary("all", common)
PY
fi

tag=$1
shift
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
seeds=${SEEDS:-$(seq 200000 200099)}
scenes=(../shared/data/sun3d_studyroom_f0935)
for seed in $seeds; do
  if [ "$seed" -lt 200050 ]; then d=runs/valwide/scenes/s$seed; style=classic; else d=runs/valwide/scenes/r$seed; style=real; fi
  mkdir -p runs/valwide/scenes
  [ -f "$d/.done" ] || { nice -n 19 "$bin" synth --seed "$seed" --frames 40 --size 320x240 --style $style --out "$d" --quiet && touch "$d/.done"; }
  scenes+=("$d")
done
SCENES="${scenes[*]}" ROOT=runs/mapwide BIN="$bin" tools/map/validate.sh "$tag" "$@" | tail -n 2
