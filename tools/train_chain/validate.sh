#!/usr/bin/env bash
# Validation that measures what users get (issue 30, SPEC.md §13.10): the full mapper, `densefeat
# eval` with every flag at its default, on the validation scenes of SPEC §3a, for the chain's latest
# weights. Appends to docs/training/chain_NAME/validation.csv, redraws validation.png and keeps the
# best weights by the mean learned-TV δ<1.25 (best_weights.safetensors).
#
#   tools/train_chain/validate.sh NAME [WEIGHTS]
#
# Scenes: SUN3D f0935 keyframes 15, 25, 35 (real), classic renders 200000-200005 and realistic renders
# 200050-200052 (40 frames, 320x240) at keyframe 20. RGB methods do not depend on the weights:
# they are run once per scene and kept in runs/val/rgb_*; delete those folders when the mapper's
# defaults change (they were stale at λ 100 until 2026-12-03 afternoon, after RGB's default became 300).
set -euo pipefail
cd "$(dirname "$0")/../.."

name=${1:-b1s2}
run=runs/chain_$name
kept=docs/training/chain_$name
weights=${2:-$run/weights.safetensors}
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
# The plot at the end needs matplotlib: say so before the evaluations, not after them.
python3 -c "import matplotlib" 2>/dev/null || {
  echo "validate.sh: python3 cannot import matplotlib (needed for $kept/validation.png and the best-weights pick): pip install matplotlib" >&2
  exit 1
}
mkdir -p runs/val "$kept"
snap=runs/val/snap_$name.safetensors
cp "$weights" "$snap"
# The step, from the weights' provenance ("densefeat train: step N of M; ...").
step=$(grep -a -o 'densefeat train: step [0-9]*' "$snap" | head -1 | awk '{print $4}')
step=${step:-0}

. tools/train_chain/val_scenes.sh
val_scenes "$bin"
scenes=()
for d in "${VAL_SCENES[@]}"; do scenes+=("$d:20"); done
scenes+=("../shared/data/sun3d_studyroom_f0935:15:10:35")

csv=$kept/validation.csv
[ -f "$csv" ] || echo "step,scene,method,rms,delta_1.25" > "$csv"
for sk in "${scenes[@]}"; do
  seq=${sk%%:*}; kf=${sk#*:}; scene=$(basename "$seq")
  case "$kf" in *:*) kfs=$kf ;; *) kfs="$kf:10:$kf" ;; esac
  rgb=runs/val/rgb_$scene
  if [ ! -f "$rgb/table.csv" ]; then
    nice -n 19 "$bin" eval --sequence "$seq" --keyframes "$kfs" --methods rgb-wta,rgb-tv --out "$rgb" > /dev/null 2>&1
  fi
  out=runs/val/learned_${name}_$scene
  nice -n 19 "$bin" eval --sequence "$seq" --keyframes "$kfs" --methods learned-wta,learned-tv \
    --weights "$snap" --out "$out" > /dev/null 2>&1
  for t in "$rgb/table.csv" "$out/table.csv"; do
    # table.csv: method,rms,log_rms,abs_rel,sq_rel,delta_1.1,delta_1.25,... (the full-coverage rows).
    awk -F, -v step="$step" -v scene="$scene" 'NR > 1 && $1 !~ /@/ { print step "," scene "," $1 "," $2 "," $7 }' "$t" >> "$csv"
  done
done
python3 tools/train_chain/plot_validation.py "$csv" "$kept/validation.png" "$kept/best.txt" "$step" \
  && if [ "$(cat "$kept/best.txt")" = "$step" ]; then cp "$snap" "$kept/best_weights.safetensors"; fi
tail -n +2 "$csv" | awk -F, -v s="$step" '$1 == s' | awk -F, '{ sum[$3] += $5; n[$3]++ } END { for (m in sum) printf "%s mean δ<1.25 %.4f over %d scenes\n", m, sum[m] / n[m], n[m] }'
