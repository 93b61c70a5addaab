#!/usr/bin/env bash
# `densefeat map` on the validation scenes of issue 31 (SPEC.md §3a, §16): SUN3D f0935 and renders
# 200000-200004, 200050, 200051 (validate.sh's 40-frame 320x240 sequences), every flag at its default
# plus the flags given; prints F-score at 2 / 5 / 10 cm (precision / recall at 5 cm) per scene and
# the mean at 5 cm.
#
#   tools/map/validate.sh TAG [map flags...]
#
# Writes runs/mapval/TAG/<scene>/ (map's folders) and runs/mapval/TAG/fscore.csv.
# tools/map/test_scenes.sh runs the same loop on the test scenes: it sets ROOT (runs/maptest) and
# SCENES (the sequence folders, space-separated).
set -euo pipefail
cd "$(dirname "$0")/../.."

tag=$1
shift
bin=${BIN:-target/release/densefeat}
[ -x "$bin" ] || cargo build --release
root=${ROOT:-runs/mapval}/$tag
mkdir -p "$root"
if [ -n "${SCENES:-}" ]; then
  read -r -a seqs <<< "$SCENES"
else
  seqs=(../shared/data/sun3d_studyroom_f0935)
  for s in s200000 s200001 s200002 s200003 s200004 r200050 r200051; do
    [ -d runs/val/$s ] || { echo "runs/val/$s missing: run tools/train_chain/validate.sh first" >&2; exit 1; }
    seqs+=(runs/val/$s)
  done
fi
csv=$root/fscore.csv
echo "scene,f2,f5,precision5,recall5,f10,seconds_per_keyframe,keyframes" > "$csv"
for seq in "${seqs[@]}"; do
  scene=$(basename "$seq")
  echo "$(date -u +%T) $scene" >&2
  nice -n 5 "$bin" map --sequence "$seq" --out "$root/$scene" "$@" > "$root/$scene.log" 2>&1
  python3 - "$root/$scene/map.json" "$scene" >> "$csv" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
st = {round(s["threshold"], 3): s for s in d["metrics"]["standard"]}
f5 = st[0.05]
# None when every keyframe was reused (a fusion-only re-run into a copy of an earlier run's folders).
spk = d["seconds_per_keyframe"] if d["seconds_per_keyframe"] is not None else float("nan")
print(f"{sys.argv[2]},{st[0.02]['fscore']:.4f},{f5['fscore']:.4f},{f5['precision']:.4f},{f5['recall']:.4f},"
      f"{st[0.1]['fscore']:.4f},{spk:.2f},{len(d['keyframes'])}")
PY
done
python3 - "$csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print("| scene | keyframes | F @ 2 cm | F @ 5 cm (P / R) | F @ 10 cm | s per keyframe |")
print("|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['scene']} | {r['keyframes']} | {float(r['f2']):.3f} | {float(r['f5']):.3f} ({float(r['precision5']):.3f} / "
          f"{float(r['recall5']):.3f}) | {float(r['f10']):.3f} | {float(r['seconds_per_keyframe']):.1f} |")
renders = [r for r in rows if r["scene"][:1] in ("s", "r") and not r["scene"].startswith("sun3d")]
for name, group in (("renders", renders), ("all", rows)):
    if group:
        m = {k: sum(float(r[k]) for r in group) / len(group) for k in ("f2", "f5", "f10")}
        print(f"| **mean, {name} ({len(group)})** | | {m['f2']:.3f} | **{m['f5']:.3f}** | {m['f10']:.3f} | |")
PY
