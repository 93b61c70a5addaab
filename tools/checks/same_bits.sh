#!/usr/bin/env bash
# Same bits before and after a change that should move no number (issue 33's refactors): runs
# demo, reconstruct, eval, map, features and train with two binaries on the shipped fixture and
# compares every output file byte for byte, except the lines that carry wall times.
#
#   tools/checks/same_bits.sh OLD_BINARY NEW_BINARY [WORK_DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
old=$1; new=$2; work=${3:-runs/same_bits}
fx=fixtures/synthetic/room_s1
rm -rf "$work"; mkdir -p "$work"
run() {  # run NAME ARGS... (the output folder or file is $work/<which>/NAME)
  local name=$1; shift
  for which in old new; do
    local bin=$old; [ $which = new ] && bin=$new
    mkdir -p "$work/$which"
    "$bin" "$@" --out "$work/$which/$name" > "$work/$which/$name.log" 2>&1 \
      || { echo "$which $name failed: see $work/$which/$name.log" >&2; exit 1; }
  done
}
run demo demo --window 5,5
run reconstruct reconstruct --sequence $fx --keyframe 20 --window 5,5 --features learned
run eval eval --sequence $fx --keyframes 10:10:30 --window 4,4
run map map --sequence $fx --frames 0:20 --window 3,3
run features.npy features $fx/images/00020.png
run train train --synthetic-scenes 2 --synthetic-val-scenes 1 --crop 96x64 --bins 32 --steps 3 --batch 1 \
  --val-every 3 --val-per-source 1 --ckpt-every 3 --threads 2 --quiet
# Files that carry wall times are compared without them: JSON without the keys that hold seconds,
# RSS or rates, log.csv without its pairs_per_s and elapsed_s columns; every other file byte for byte.
python3 - "$work" <<'PY'
import csv, json, os, sys
work = sys.argv[1]
TIMING = ("seconds", "timings", "wall", "elapsed", "peak_rss", "rss", "per_s", "_ms", "s_per_keyframe")
def scrub(v):
    if isinstance(v, dict):
        return {k: scrub(x) for k, x in v.items() if not any(t in k for t in TIMING)}
    if isinstance(v, list):
        return [scrub(x) for x in v]
    return v
def csv_rows(path):
    rows = list(csv.reader(open(path)))
    drop = {i for i, h in enumerate(rows[0]) if h in ("pairs_per_s", "frames_per_s", "elapsed_s")}
    return [[c for i, c in enumerate(r) if i not in drop] for r in rows]
def safetensors(path):
    import struct
    raw = open(path, "rb").read()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    meta = header.pop("__metadata__", {})
    body = raw[8 + n:]
    return meta, {k: (v["dtype"], v["shape"], body[v["data_offsets"][0]:v["data_offsets"][1]]) for k, v in header.items()}
bad, n = [], 0
old = os.path.join(work, "old")
for root, _, files in os.walk(old):
    for f in sorted(files):
        if f.endswith(".log") or f == "timings.md":  # wall times only
            continue
        a = os.path.join(root, f)
        rel = os.path.relpath(a, old)
        b = os.path.join(work, "new", rel)
        n += 1
        if not os.path.exists(b):
            bad.append("missing in new: " + rel)
        elif open(a, "rb").read() == open(b, "rb").read():
            continue
        elif f.endswith(".json"):
            if scrub(json.load(open(a))) != scrub(json.load(open(b))):
                bad.append("differs: " + rel)
        elif f.endswith(".safetensors"):
            # Same metadata and tensors, whatever the order in the file (the safetensors crate's
            # writer ordered its metadata by hash until 2026-12-03).
            if safetensors(a) != safetensors(b):
                bad.append("differs: " + rel)
        elif f == "log.csv":
            if csv_rows(a) != csv_rows(b):
                bad.append("differs: " + rel)
        else:
            bad.append("differs: " + rel)
if bad:
    print("\n".join(bad))
    sys.exit(1)
print(f"same bits: {n} files of demo, reconstruct, eval, map, features, train")
PY
